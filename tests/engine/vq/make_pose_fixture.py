"""Writes tests/engine/vq/pose_fixture.json: the Python reference of the engine's pose reconstruction.

Takes 24 frames of a converted CMU take (training/cache/motion), encodes them (representation.encode), adds
noise (decoded poses are not rigid), then runs the reference decode -> project_bone_lengths ->
local_rotations. The C++ PoseReconstructor must reproduce positions and rotations from (upper, lower).
Usage: OMP_WAIT_POLICY=PASSIVE /usr/bin/python3 tests/engine/vq/make_pose_fixture.py
"""
import json
import pathlib
import sys

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))
from training.data import representation as rep  # noqa: E402
from training.data import rotations as rot  # noqa: E402
from training.data import skeleton as sk  # noqa: E402


def main():
  skel = sk.load_skeleton()
  pos = np.load(ROOT / "training/cache/motion/cmu_60_01.npz")["positions"][100:124].astype(np.float64)
  upper, lower = rep.encode(pos)
  rng = np.random.default_rng(0)
  upper = upper + rng.normal(0, 0.01, upper.shape)
  lower[:, :27] += rng.normal(0, 0.01, (len(lower), 27))
  lower[:, 29] += 0.05  # keep turning so yaw integration matters
  upper, lower = upper.astype(np.float32).astype(np.float64), lower.astype(np.float32).astype(np.float64)
  decoded = rep.decode(upper, lower)
  projected = sk.project_bone_lengths(decoded, skel)
  local = rot.local_rotations(projected, skel)
  out = {"skeleton": skel.as_json(), "upper": upper.tolist(), "lower": lower.tolist(),
         "positions": projected.tolist(), "rotations": local.tolist()}
  path = ROOT / "tests/engine/vq/pose_fixture.json"
  path.write_text(json.dumps(out, separators=(",", ":")))
  print("wrote", path, path.stat().st_size, "bytes")


if __name__ == "__main__":
  main()
