#!/usr/bin/env bash
# Creates .venv (sees Debian's torch and numpy through --system-site-packages) with the PyPI packages used
# only by tests and reports: librosa, the field's reference audio analysis.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ ! -x .venv/bin/python ]; then
  /usr/bin/python3 -m venv --system-site-packages .venv
fi
if ! .venv/bin/python -c "import librosa" 2>/dev/null; then
  .venv/bin/pip install -q -r training/requirements-test.txt
fi
