#!/usr/bin/env bash
# Installs web/'s pinned npm packages: `npm ci` (exactly the lock file). A registry mirror that lacks other
# platforms' optional packages (rollup's android/darwin/win32 binaries) makes npm ci refuse a lock written
# against another registry ("not in sync"); then this installs from the same lock without rewriting it
# (`npm install --no-save`). Any other npm ci failure is an error.
# Usage: scripts/web-install.sh      (from scripts/web-test.sh and scripts/demo.sh)
set -euo pipefail
cd "$(dirname "$0")/../web"
log="$(mktemp)"
trap 'rm -f "$log"' EXIT
if ! npm ci --no-audit --no-fund --loglevel=error 2>"$log"; then
  grep -q 'in sync' "$log" || { cat "$log" >&2; exit 1; }
  echo "web-install.sh: npm ci refused the lock (registry without other platforms' packages); npm install --no-save"
  npm install --no-save --no-audit --no-fund --loglevel=error
fi
