#!/usr/bin/env bash
# Creates .venv (sees Debian's torch and numpy through --system-site-packages) with the PyPI packages used
# only by tests and reports: librosa, the field's reference audio analysis.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ ! -x .venv/bin/python ]; then
  /usr/bin/python3 -m venv --system-site-packages .venv
fi
# Installs when a package is missing or not at the pinned version (an older .venv may hold a numba that crashes).
if ! .venv/bin/python - training/requirements-test.txt <<'PY' 2>/dev/null
import sys
from importlib.metadata import version
pins = [l.split("#")[0].strip() for l in open(sys.argv[1])]
sys.exit(any(version(name) != want for name, want in (p.split("==") for p in pins if p)))
PY
then
  .venv/bin/pip install -q -r training/requirements-test.txt
fi
