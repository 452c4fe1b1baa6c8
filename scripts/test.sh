#!/usr/bin/env bash
# Builds the project with a CMake preset and runs every test suite: GoogleTest (ctest) and pytest.
# Usage: scripts/test.sh [release|asan|tsan|debug]   (default: release)
set -euo pipefail
cd "$(dirname "$0")/.."
preset="${1:-release}"
jobs="${DANCE_JOBS:-$(nproc)}"

scripts/setup-venv.sh >/dev/null
cmake --preset "$preset" >/dev/null
cmake --build --preset "$preset" -j "$jobs"

if [ "$preset" = release ]; then build_dir=build; else build_dir="build-$preset"; fi
(cd "$build_dir" && ctest --output-on-failure -j "$jobs" --timeout 900)

if [ "$preset" = release ] && [ -d tests/training ]; then
  OMP_WAIT_POLICY=PASSIVE DANCE_BUILD_DIR="$PWD/$build_dir" .venv/bin/python -m pytest -q tests/training
fi
if [ "$preset" = release ] && [ -f web/package.json ] && [ -d tests/web ]; then
  scripts/web-test.sh
fi
echo "test.sh: all $preset tests passed"
