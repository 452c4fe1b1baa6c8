#!/usr/bin/env bash
# The two-command demo: installs the Debian packages, builds the release preset (and the web page if it
# exists), starts dance-server on the committed model, streams a real song from Debian's
# fretsonfire-songs-sectoid with dance-client in real time, writes out/dance.json and out/dance.bvh, and
# prints the URL to watch it live. The server keeps running after the song (so the page can still be
# opened) until Ctrl-C; --no-wait exits when the song is done (CI).
#
# Usage: scripts/demo.sh [--no-wait] [--fast] [--song "Feelings"] [--port 50051] [--http-port 8080]
# DANCE_BIN_DIR=/path/to/build/bin skips installing and building and uses those binaries.
set -euo pipefail
cd "$(dirname "$0")/.."
root="$PWD"

wait_at_end=1
realtime=--realtime
song_name="Feelings"
port="${DANCE_PORT:-50051}"
http_port="${DANCE_HTTP_PORT:-8080}"
while [ $# -gt 0 ]; do
  case "$1" in
    --no-wait) wait_at_end=0 ;;
    --fast) realtime="" ;;
    --song) song_name="$2"; shift ;;
    --port) port="$2"; shift ;;
    --http-port) http_port="$2"; shift ;;
    -h|--help) sed -n '2,9p' "$0"; exit 0 ;;
    *) echo "demo.sh: unknown argument $1" >&2; exit 2 ;;
  esac
  shift
done

step() { printf '\n== %s\n' "$*"; }

bin="${DANCE_BIN_DIR:-build/bin}"
if [ -z "${DANCE_BIN_DIR:-}" ]; then
  step "1/5 Debian packages (scripts/install-deps.sh)"
  scripts/install-deps.sh

  step "2/5 Build (release preset)"
  jobs="${DANCE_JOBS:-$(nproc)}"
  cmake --preset release >/dev/null
  cmake --build --preset release -j "$jobs" --target dance-server dance-client
fi

if [ -z "${DANCE_BIN_DIR:-}" ] && [ -f web/package.json ]; then
  step "2b/5 Web page (npm ci && npm run build in web/)"
  if command -v npm >/dev/null; then
    scripts/web-install.sh && (cd web && npm run build)
  else
    echo "npm not found: the server will show a fallback page at /" >&2
  fi
fi

step "3/5 Model and song"
model=models/default.dncw
[ -f "$model" ] || model=models/test-tiny.dncw
if [ ! -f "$model" ]; then
  echo "demo.sh: no model in models/ (expected models/default.dncw or models/test-tiny.dncw)" >&2
  exit 1
fi
songs=$(dpkg -L fretsonfire-songs-sectoid | grep '/song.ogg$' || true)
song=$(printf '%s\n' "$songs" | grep -F "/$song_name/" | head -n1 || true)
[ -n "$song" ] || song=$(printf '%s\n' "$songs" | head -n1)
if [ ! -f "$song" ]; then
  echo "demo.sh: no song.ogg from fretsonfire-songs-sectoid (is the package installed?)" >&2
  exit 1
fi
echo "model: $model"
echo "song:  $song"

step "4/5 dance-server on port $port (HTTP $http_port)"
mkdir -p out
"$bin/dance-server" --port "$port" --http-port "$http_port" --model "$model" \
  --web-root "$root/web/dist" >out/server.log 2>&1 &
server_pid=$!
cleanup() {
  if kill -0 "$server_pid" 2>/dev/null; then
    kill -TERM "$server_pid" 2>/dev/null || true
    wait "$server_pid" 2>/dev/null || true
  fi
}
trap cleanup EXIT
trap 'echo; echo "stopping dance-server"; exit 0' INT TERM
for _ in $(seq 1 100); do
  if "$bin/dance-client" info --server "localhost:$port" >/dev/null 2>&1; then break; fi
  if ! kill -0 "$server_pid" 2>/dev/null; then
    echo "demo.sh: dance-server failed to start:" >&2
    cat out/server.log >&2
    exit 1
  fi
  sleep 0.1
done

step "5/5 Streaming the song ${realtime:+in real time }(watch it live: http://localhost:$http_port/)"
echo "Watch it live: http://localhost:$http_port/"
"$bin/dance-client" --server "localhost:$port" --audio "$song" $realtime \
  --out out/dance.json --bvh out/dance.bvh

echo
echo "Done: out/dance.json (dance-motion/v1) and out/dance.bvh"
echo "Server log: out/server.log   Metrics: http://localhost:$http_port/metrics"
if [ "$wait_at_end" = 1 ]; then
  echo "dance-server keeps running: open http://localhost:$http_port/ (Ctrl-C to stop)"
  wait "$server_pid"
fi
