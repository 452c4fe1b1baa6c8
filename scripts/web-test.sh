#!/usr/bin/env bash
# Browser visualizer tests: installs web/'s pinned npm packages (npm ci), builds the page into web/dist
# (what dance-server serves at /), then runs tests/web with node's test runner: unit tests of the page's
# logic and the end-to-end test in headless Debian Chromium against a real dance-server.
# Usage: scripts/web-test.sh            (called by scripts/test.sh when web/package.json and tests/web exist)
# Env:   DANCE_BUILD_DIR (default ./build: bin/dance-server), DANCE_MODEL (default models/test-tiny.dncw),
#        DANCE_WEB_SKIP_INSTALL=1 (reuse web/node_modules), DANCE_WEB_SCREENSHOTS=DIR (save screenshots).
set -euo pipefail
cd "$(dirname "$0")/.."
export DANCE_BUILD_DIR="${DANCE_BUILD_DIR:-$PWD/build}"
export OMP_WAIT_POLICY=PASSIVE

for tool in node npm; do
  command -v "$tool" >/dev/null || { echo "web-test.sh: $tool not found (scripts/install-deps.sh)" >&2; exit 1; }
done
[ -x "${CHROMIUM:-/usr/bin/chromium}" ] || { echo "web-test.sh: no ${CHROMIUM:-/usr/bin/chromium}" >&2; exit 1; }

if [ "${DANCE_WEB_SKIP_INSTALL:-0}" != 1 ] || [ ! -d web/node_modules ]; then
  scripts/web-install.sh
fi
(cd web && npm run --silent build -- --logLevel warn)
node --test --test-reporter=spec tests/web/*.test.mjs
echo "web-test.sh: browser tests passed"
