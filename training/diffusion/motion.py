"""The diffusion model's motion vector (docs/diffusion.md section 2) and the window canonical frame.

Per frame (D = 78): pelvis (x, y, z) in the window's frame (3); the facing yaw as (sin, cos) (2); joints 1..23
relative to the pelvis in the facing frame, R_y(-theta) (J_j - J_pelvis) (69); foot contacts of joints 7, 8,
10, 11 (left ankle, right ankle, left foot, right foot) (4), 1 when the joint moves less than CONTACT_SPEED m/s, else 0.
The window's frame: the world translated so the first frame's pelvis is above the origin and rotated so it
faces +Z (positions_in_frame / frame_of).

    v = motion_vector(canonical_positions)       # (T, 78)
    p = positions_of(v)                          # (T, 24, 3), the inverse (contacts ignored)
"""
from __future__ import annotations

import numpy as np

from training.data import representation as rep
from training.data.skeleton import FOOT_JOINTS

POSE_DIM = 78
ROOT, HEADING, LOCAL, CONTACT = slice(0, 3), slice(3, 5), slice(5, 74), slice(74, 78)
CONTACT_SPEED = 0.3   # m/s; at 30 fps 1 cm per frame
FPS = 30


def frame_of(positions: np.ndarray) -> tuple[float, np.ndarray]:
  """A frame's (yaw, pelvis xz): the canonical frame it starts."""
  p = np.asarray(positions, dtype=np.float64)
  return float(rep.facing_yaw(p[None])[0]), p[0, [0, 2]].copy()


def positions_in_frame(positions: np.ndarray, yaw: float, origin_xz: np.ndarray) -> np.ndarray:
  """World positions (..., 24, 3) -> the frame whose origin is origin_xz (on the floor) facing yaw."""
  p = np.asarray(positions, dtype=np.float64).copy()
  p[..., 0] -= origin_xz[0]
  p[..., 2] -= origin_xz[1]
  return np.einsum("ij,...j->...i", rep.rot_y(np.float64(-yaw)), p)


def positions_from_frame(positions: np.ndarray, yaw: float, origin_xz: np.ndarray) -> np.ndarray:
  """The inverse of positions_in_frame."""
  p = np.einsum("ij,...j->...i", rep.rot_y(np.float64(yaw)), np.asarray(positions, dtype=np.float64))
  p[..., 0] += origin_xz[0]
  p[..., 2] += origin_xz[1]
  return p


def contacts(positions: np.ndarray) -> np.ndarray:
  """(T, 24, 3) -> (T, 4): 1 where the foot joint's speed to the next frame is below CONTACT_SPEED (the
  last frame repeats the one before)."""
  p = np.asarray(positions, dtype=np.float64)[:, list(FOOT_JOINTS)]
  t = len(p)
  c = np.zeros((t, 4))
  if t > 1:
    speed = np.linalg.norm(p[1:] - p[:-1], axis=-1) * FPS
    c[:-1] = speed < CONTACT_SPEED
    c[-1] = c[-2]
  return c


def motion_vector(positions: np.ndarray) -> np.ndarray:
  """(T, 24, 3) in the window's frame -> (T, 78) float64."""
  p = np.asarray(positions, dtype=np.float64)
  t = len(p)
  theta = rep.facing_yaw(p)
  rel = np.einsum("tij,tnj->tni", rep.rot_y(-theta), p - p[:, :1])
  return np.concatenate([p[:, 0], np.sin(theta)[:, None], np.cos(theta)[:, None], rel[:, 1:].reshape(t, 69),
                         contacts(p)], axis=-1)


def positions_of(v: np.ndarray) -> np.ndarray:
  """(T, 78) -> (T, 24, 3): pelvis + R_y(atan2(sin, cos)) rel (the heading pair need not be unit)."""
  v = np.asarray(v, dtype=np.float64)
  t = len(v)
  theta = np.arctan2(v[:, 3], v[:, 4])
  rel = np.zeros((t, 24, 3))
  rel[:, 1:] = v[:, LOCAL].reshape(t, 23, 3)
  return np.einsum("tij,tnj->tni", rep.rot_y(theta), rel) + v[:, None, ROOT]
