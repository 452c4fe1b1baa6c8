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
  # Python side (training, evaluation, example client, tests).
  python3 python3-venv python3-pip python3-numpy python3-scipy python3-matplotlib python3-pytest
  python3-torch libopenblas0-pthread python3-tqdm python3-grpcio python3-protobuf python3-mido
  # Audio tools and real music.
  sox libsox-fmt-all fretsonfire-songs-sectoid fretsonfire-songs-muldjord
  # Browser tests (Node.js and npm come with the machine image; Debian's would downgrade them).
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
