"""A small BVH reader and forward kinematics (global joint positions), written for this project.

Usage:
  bvh = read_bvh("dance.bvh")
  pos = bvh.global_positions()          # (T, n_joints + n_end_sites, 3) in the file's units
  pos[:, bvh.index("lShin")]
End sites are named "<parent>_end".
"""
from __future__ import annotations

import dataclasses
import pathlib

import numpy as np


@dataclasses.dataclass
class Bvh:
  names: list[str]               # joints then end sites, parents before children
  parents: list[int]             # -1 for the root
  offsets: np.ndarray            # (N, 3) rest offset from the parent
  channels: list[list[str]]      # per joint, e.g. ["Xposition", ..., "Zrotation"]; [] for end sites
  motion: np.ndarray             # (T, n_channels) raw channel values
  frame_time: float              # seconds

  @property
  def fps(self) -> float:
    return 1.0 / self.frame_time

  def index(self, name: str) -> int:
    return self.names.index(name)

  def global_positions(self) -> np.ndarray:
    """Forward kinematics: (T, N, 3). Rotation channels are Euler angles in degrees, applied in the
    order they are listed (intrinsic), i.e. R = R_c1 @ R_c2 @ R_c3; the child's global position is
    parent_pos + parent_rot @ (offset + translation channels of the child, if any)."""
    t = self.motion.shape[0]
    n = len(self.names)
    pos = np.zeros((t, n, 3))
    rot = np.zeros((t, n, 3, 3))
    col = 0
    for j in range(n):
      local_t = np.broadcast_to(self.offsets[j], (t, 3)).copy()
      local_r = np.broadcast_to(np.eye(3), (t, 3, 3)).copy()
      for ch in self.channels[j]:
        v = self.motion[:, col]
        col += 1
        axis = "XYZ".index(ch[0])
        if ch.endswith("position"):
          local_t[:, axis] = v if self.parents[j] < 0 else local_t[:, axis] + v
        else:
          local_r = local_r @ _axis_rotation(axis, np.deg2rad(v))
      p = self.parents[j]
      if p < 0:
        pos[:, j] = local_t
        rot[:, j] = local_r
      else:
        pos[:, j] = pos[:, p] + np.einsum("tij,tj->ti", rot[:, p], local_t)
        rot[:, j] = rot[:, p] @ local_r
    return pos


def _axis_rotation(axis: int, angle: np.ndarray) -> np.ndarray:
  c, s = np.cos(angle), np.sin(angle)
  m = np.zeros(angle.shape + (3, 3))
  a, b = [(1, 2), (2, 0), (0, 1)][axis]
  m[..., axis, axis] = 1.0
  m[..., a, a] = c
  m[..., a, b] = -s
  m[..., b, a] = s
  m[..., b, b] = c
  return m


def read_bvh(path: str | pathlib.Path) -> Bvh:
  tokens = pathlib.Path(path).read_text().split()
  names, parents, offsets, channels = [], [], [], []
  stack: list[int] = []
  i = 0
  pending = None
  while tokens[i] != "MOTION":
    tok = tokens[i]
    if tok in ("ROOT", "JOINT"):
      pending = tokens[i + 1]
      i += 2
    elif tok == "End":  # "End Site"
      pending = names[stack[-1]] + "_end"
      i += 2
    elif tok == "{":
      names.append(pending)
      parents.append(stack[-1] if stack else -1)
      offsets.append([0.0, 0.0, 0.0])
      channels.append([])
      stack.append(len(names) - 1)
      i += 1
    elif tok == "}":
      stack.pop()
      i += 1
    elif tok == "OFFSET":
      offsets[stack[-1]] = [float(x) for x in tokens[i + 1:i + 4]]
      i += 4
    elif tok == "CHANNELS":
      k = int(tokens[i + 1])
      channels[stack[-1]] = tokens[i + 2:i + 2 + k]
      i += 2 + k
    elif tok == "HIERARCHY":
      i += 1
    else:
      raise ValueError(f"{path}: unexpected token {tok!r} in the hierarchy")
  # MOTION Frames: T Frame Time: dt values...
  if tokens[i + 1] != "Frames:" or tokens[i + 3:i + 5] != ["Frame", "Time:"]:
    raise ValueError(f"{path}: malformed MOTION header")
  t = int(tokens[i + 2])
  frame_time = float(tokens[i + 5])
  n_ch = sum(len(c) for c in channels)
  values = np.asarray(tokens[i + 6:], dtype=np.float64)
  if values.size < t * n_ch:
    raise ValueError(f"{path}: {values.size} motion values, expected {t} x {n_ch}")
  motion = values[:t * n_ch].reshape(t, n_ch)
  return Bvh(names, parents, np.asarray(offsets), channels, motion, frame_time)
