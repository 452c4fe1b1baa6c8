#!/usr/bin/env bash
# Builds the project with a CMake preset and runs every test suite: GoogleTest (ctest) and pytest.
# Usage: scripts/test.sh [release|asan|tsan|debug]   (default: release)
set -euo pipefail
cd "$(dirname "$0")/.."
preset="${1:-release}"
jobs="${DANCE_JOBS:-$(nproc)}"

if [ "$preset" = release ]; then build_dir=build; else build_dir="build-$preset"; fi

if [ "$preset" = tsan ]; then
  # TSan covers the multi-threaded part only: the server and client suites (the engine is single-threaded
  # per session and runs under ASan). Builds just their targets; suppressions: cmake/tsan.supp.
  tsan_tests=(server_unit_test perform_integration_test bad_client_integration_test http_integration_test
              dance_file_test client_integration_test)
  cmake --preset tsan >/dev/null
  cmake --build --preset tsan -j "$jobs" --target "${tsan_tests[@]}" dance-server
  (cd "$build_dir" && ctest --output-on-failure -j "$jobs" --timeout 900 \
     -R "^($(IFS='|'; echo "${tsan_tests[*]}")|python_client_test)\$")
  echo "test.sh: all tsan tests passed"
  exit 0
fi

scripts/setup-venv.sh >/dev/null
cmake --preset "$preset" >/dev/null
cmake --build --preset "$preset" -j "$jobs"

(cd "$build_dir" && ctest --output-on-failure -j "$jobs" --timeout 900)

if [ "$preset" = release ] && [ -d tests/training ]; then
  OMP_WAIT_POLICY=PASSIVE DANCE_BUILD_DIR="$PWD/$build_dir" .venv/bin/python -m pytest -q tests/training
fi
if [ "$preset" = release ] && [ -f web/package.json ] && [ -d tests/web ]; then
  scripts/web-test.sh
fi
echo "test.sh: all $preset tests passed"
