#!/usr/bin/env bash
# A local cluster on loopback (docs/server.md, "Several servers"): redis-server (the session registry),
# N dance-servers and haproxy in front of them (deploy/haproxy/haproxy.cfg.in), every port a free one.
# Runs the load tester through the proxy, checks the cluster while it runs (tests/server/cluster_check.py:
# ListSessions, Watch and /ws/watch reaching sessions on every server), reports how the performers
# spread over the servers, then stops everything it started.
#
#   scripts/cluster.sh [--servers 3] [--streams 90] [--duration 20] [--audio FILE] [--model M] [--build DIR]
#   scripts/cluster.sh --ci      # CI size: 3 servers, 12 streams of 8 s, the tiny model, a click track
#
# Needs redis-server and haproxy (scripts/install-deps.sh) and a build (default build/, or --build DIR /
# $DANCE_BUILD_DIR). Exit status 0 = every check passed; 77 = redis-server or haproxy missing (skipped).
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
servers=3 streams=90 duration=20 audio="" model="" build="${DANCE_BUILD_DIR:-$root/build}" ci=0
while [ $# -gt 0 ]; do
  case "$1" in
    --servers) servers=$2; shift 2 ;;
    --streams) streams=$2; shift 2 ;;
    --duration) duration=$2; shift 2 ;;
    --audio) audio=$2; shift 2 ;;
    --model) model=$2; shift 2 ;;
    --build) build=$2; shift 2 ;;
    --ci) ci=1 streams=12 duration=8; shift ;;
    *) echo "cluster.sh: unknown argument $1" >&2; exit 2 ;;
  esac
done
for tool in redis-server haproxy; do
  command -v "$tool" >/dev/null || { echo "cluster.sh: $tool not installed (scripts/install-deps.sh); skipped"; exit 77; }
done
bin="$build/bin"
[ -x "$bin/dance-server" ] && [ -x "$bin/dance-client" ] || { echo "cluster.sh: no $bin/dance-server (build first)" >&2; exit 2; }

work=$(mktemp -d /tmp/dance-cluster.XXXXXX)
pids=()
cleanup() {
  local rc=$?
  # Only what this script started, by pid: TERM (servers drain), then KILL whatever is left after 10 s.
  for p in "${pids[@]}"; do kill -TERM "$p" 2>/dev/null || true; done
  for _ in $(seq 100); do
    local alive=0
    for p in "${pids[@]}"; do kill -0 "$p" 2>/dev/null && alive=1; done
    [ $alive = 0 ] && break
    sleep 0.1
  done
  for p in "${pids[@]}"; do kill -KILL "$p" 2>/dev/null || true; done
  [ $rc = 0 ] || { echo "cluster.sh: logs in $work"; exit $rc; }
  rm -rf "$work"
}
trap cleanup EXIT
trap 'exit 130' INT TERM

# Free loopback ports, all bound at once so they differ (released just before use).
read -r -a ports <<<"$(/usr/bin/python3 - "$((2 * servers + 2))" <<'EOF'
import socket, sys
socks = [socket.socket() for _ in range(int(sys.argv[1]))]
for s in socks: s.bind(("127.0.0.1", 0))
print(" ".join(str(s.getsockname()[1]) for s in socks))
EOF
)"
redis_port=${ports[0]} proxy_port=${ports[1]}

if [ $ci = 1 ] && [ -z "$model" ]; then model="$root/models/test-tiny.dncw"; fi
[ -n "$model" ] || model="$root/models/default.dncw"
if [ -z "$audio" ]; then
  audio="$work/clicks.wav"  # 10 s of clicks at 120 BPM over a tone, 24 kHz mono
  /usr/bin/python3 - "$audio" <<'EOF'
import math, struct, sys, wave
rate = 24000
with wave.open(sys.argv[1], "wb") as w:
    w.setnchannels(1); w.setsampwidth(2); w.setframerate(rate)
    frames = bytearray()
    for i in range(10 * rate):
        t = i / rate
        x = 0.2 * math.sin(2 * math.pi * 220 * t) + (0.7 if (t % 0.5) < 0.01 else 0.0)
        frames += struct.pack("<h", int(max(-1, min(1, x)) * 32000))
    w.writeframes(bytes(frames))
EOF
fi

wait_http() {  # wait_http PORT PATH: until it answers at all (any status), 30 s at most
  /usr/bin/python3 - "$1" "$2" <<'EOF'
import sys, time, urllib.request, urllib.error
for _ in range(300):
    try:
        urllib.request.urlopen("http://127.0.0.1:%s%s" % (sys.argv[1], sys.argv[2]), timeout=1); sys.exit(0)
    except urllib.error.HTTPError: sys.exit(0)
    except OSError: time.sleep(0.1)
sys.exit(1)
EOF
}

redis-server --bind 127.0.0.1 --port "$redis_port" --save "" --appendonly no --daemonize no \
  --logfile "$work/redis.log" &
pids+=($!)

server_list="" perform_lines="" grpc_lines="" wsp_lines="" http_lines=""
for i in $(seq 1 "$servers"); do
  g=${ports[$((2 * i))]} h=${ports[$((2 * i + 1))]}
  "$bin/dance-server" --host 127.0.0.1 --port "$g" --http-port "$h" --model "$model" \
    --cluster-store "127.0.0.1:$redis_port" --server-id "s$i" --web-root "$root/web/dist" \
    --scheduler-threads 1 --max-sessions "$(( streams + 8 ))" >"$work/server$i.out" 2>"$work/server$i.log" &
  pids+=($!)
  server_list+="${server_list:+,}$g/$h"
  perform_lines+="  server s$i 127.0.0.1:$g proto h2 check-proto h1 check port $h"$'\n'
  grpc_lines+="  server s$i 127.0.0.1:$g proto h2 check-proto h1 check port $h"$'\n'
  wsp_lines+="  server s$i 127.0.0.1:$h check"$'\n'
  http_lines+="  server s$i 127.0.0.1:$h check"$'\n'
done
/usr/bin/python3 - "$root/deploy/haproxy/haproxy.cfg.in" "$work/haproxy.cfg" <<EOF
import sys
t = open(sys.argv[1]).read()
for k, v in {"@PERFORM_SERVERS@": """$perform_lines""", "@GRPC_SERVERS@": """$grpc_lines""",
             "@WS_PERFORM_SERVERS@": """$wsp_lines""", "@HTTP_SERVERS@": """$http_lines"""}.items():
    t = t.replace(k + "\n", v)
open(sys.argv[2], "w").write(t)
EOF
for i in $(seq 1 "$servers"); do
  wait_http "${ports[$((2 * i + 1))]}" /healthz || { echo "cluster.sh: server $i did not start" >&2; exit 1; }
done
DANCE_PROXY_BIND="127.0.0.1:$proxy_port" haproxy -f "$work/haproxy.cfg" -db >"$work/haproxy.log" 2>&1 &
pids+=($!)
wait_http "$proxy_port" /healthz || { echo "cluster.sh: haproxy did not start" >&2; exit 1; }
sleep 1  # the first health checks
echo "cluster.sh: redis :$redis_port, $servers servers ($server_list, gRPC/HTTP), haproxy :$proxy_port, model $(basename "$model")"

metric() {  # metric HTTP_PORT NAME: the value of an unlabelled metric
  /usr/bin/python3 -c "
import sys, urllib.request
for line in urllib.request.urlopen('http://127.0.0.1:$1/metrics', timeout=5).read().decode().splitlines():
    if line.split(' ')[0] == '$2': print(int(float(line.split(' ')[1]))); break"
}

"$bin/dance-client" load --server "127.0.0.1:$proxy_port" --audio "$audio" --streams "$streams" \
  --duration "$duration" --quiet >"$work/load.txt" 2>&1 &
load_pid=$!
pids+=($load_pid)
# Check while every stream is live: after the stagger (1 s) and a little.
sleep 3
status=0
/usr/bin/python3 "$root/tests/server/cluster_check.py" --proxy "127.0.0.1:$proxy_port" --servers "$server_list" \
  --min-sessions "$(( streams * 3 / 4 ))" || status=1
load_rc=0
wait $load_pid || load_rc=$?
echo "--- load tester through the proxy ($streams streams x ${duration} s):"
cat "$work/load.txt"
[ $load_rc = 0 ] || { echo "FAIL  the load tester exited with $load_rc"; status=1; }

# How the performers spread: sessions each server admitted.
counts=()
for i in $(seq 1 "$servers"); do counts+=("$(metric "${ports[$((2 * i + 1))]}" dance_sessions_started_total)"); done
echo "performers per server: ${counts[*]}"
/usr/bin/python3 - "$streams" "${counts[@]}" <<'EOF' || status=1
import sys
n, counts = int(sys.argv[1]), [int(c) for c in sys.argv[2:]]
mean = n / len(counts)
ok = sum(counts) == n and all(abs(c - mean) <= max(1.0, 0.2 * mean) for c in counts)
print(("ok    " if ok else "FAIL  ") + "performers spread evenly: %s for %d streams (mean %.1f, allowed +-%.1f)"
      % (counts, n, mean, max(1.0, 0.2 * mean)))
sys.exit(0 if ok else 1)
EOF
errors=$(cat "$work"/server*.log | grep -c '"level":"error"' || true)
[ "$errors" = 0 ] || { echo "FAIL  $errors error lines in the server logs"; status=1; }
[ $status = 0 ] && echo "cluster.sh: passed" || echo "cluster.sh: FAILED"
exit $status
