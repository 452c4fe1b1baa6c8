#!/usr/bin/env bash
# Builds the project with a CMake preset and runs every test suite: GoogleTest (ctest) and pytest.
# Usage: scripts/test.sh [release|asan|tsan|debug]   (default: release)
set -euo pipefail
cd "$(dirname "$0")/.."
preset="${1:-release}"
jobs="${DANCE_JOBS:-$(nproc)}"

if [ "$preset" = release ]; then build_dir=build; else build_dir="build-$preset"; fi

if [ "$preset" = tsan ]; then
  # TSan covers the multi-threaded part only and builds just its targets (no engine). The suites are the
  # server's and client's that do not run gRPC: the scheduler, sessions and sinks (with a test double
  # engine) and the client's files. The gRPC integration suites are left out on purpose: Debian's libgrpc,
  # libprotobuf and libabsl are not TSan-instrumented, so the happens-before edges of gRPC's callbacks are
  # invisible and TSan reports hundreds of false races in gRPC's headers and in every reactor; they need a
  # TSan-built gRPC. absl::Mutex is made visible by cmake/tsan_absl_mutex.cc; suppressions: cmake/tsan.supp.
  tsan_tests=(server_unit_test dance_file_test)
  cmake --preset tsan >/dev/null
  cmake --build --preset tsan -j "$jobs" --target "${tsan_tests[@]}"
  (cd "$build_dir" && ctest --output-on-failure -j "$jobs" --timeout 900 -R "^($(IFS='|'; echo "${tsan_tests[*]}"))\$")
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
