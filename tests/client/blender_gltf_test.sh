#!/usr/bin/env bash
# CTest driver for blender_gltf_import_test (label integration): generates a 10 s dance from a click track
# with dance-generate (--out JSON and --gltf .glb), imports the .glb into headless Blender and checks it
# against the JSON (blender_gltf_check.py). Exits 77 (CTest SKIP_RETURN_CODE) when blender is not on PATH.
# Usage: blender_gltf_test.sh DANCE_GENERATE MODEL.dncw [SECONDS]
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
generate="${1:?usage: blender_gltf_test.sh DANCE_GENERATE MODEL.dncw [SECONDS]}"
model="${2:?usage: blender_gltf_test.sh DANCE_GENERATE MODEL.dncw [SECONDS]}"
seconds="${3:-10}"
if ! command -v blender >/dev/null 2>&1; then
  echo "SKIP: blender is not on PATH (Debian: apt-get install blender)"
  exit 77
fi
work="$(mktemp -d "${TMPDIR:-/tmp}/blender_gltf_test.XXXXXX")"
trap 'rm -rf "$work"' EXIT
python3 - "$work/click.wav" "$seconds" <<'PY'
import math, struct, sys, wave
path, seconds, rate = sys.argv[1], float(sys.argv[2]), 22050
n, beat = int(seconds * rate), rate // 2
s = []
for i in range(n):
    t = (i % beat) / rate
    v = 0.1 * math.sin(2 * math.pi * 220 * i / rate)
    if t < 0.03:
        v += 0.8 * math.exp(-t / 0.008) * math.sin(2 * math.pi * 1000 * t)
    s.append(int(max(-1.0, min(1.0, v)) * 32767))
with wave.open(path, "wb") as w:
    w.setnchannels(1); w.setsampwidth(2); w.setframerate(rate); w.writeframes(struct.pack("<%dh" % n, *s))
PY
"$generate" --audio "$work/click.wav" --model "$model" --seed 0 --out "$work/dance.json" --gltf "$work/dance.glb"
blender --version | head -n 1
blender -b --factory-startup --python-exit-code 1 --python "$here/blender_gltf_check.py" -- \
  "$work/dance.glb" "$work/dance.json"
