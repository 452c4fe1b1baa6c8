"""Per-segment motion features for FID/Div (Bailando / AIST++ style, our own implementation).

Kinetic (72 = 24 joints x 3): per joint, over the segment, the mean horizontal kinetic energy 0.5 |v_xz|^2,
the mean vertical kinetic energy 0.5 v_y^2 (unit mass, m^2/s^2), and the mean energy expenditure
|a| |v| (m^2/s^3). Joints are taken relative to the pelvis, except the pelvis itself (global), as Bailando
does, so travelling shows in one joint and does not swamp the limbs.

Geometric (34): fractions of the segment's frames for which boolean relations between body parts hold,
in the spirit of Mueller et al.'s relational features used by AIST++ (the exact list is GEOMETRIC_NAMES;
thresholds are in metres/radians and scaled by the canonical body, which is the same for all our data).

Usage:
  segs = segments(positions, fps=30, seconds=10)       # list of (300, 24, 3)
  k = np.stack([kinetic_features(s) for s in segs]); g = np.stack([geometric_features(s) for s in segs])
"""
from __future__ import annotations

import numpy as np

from training.data.representation import facing_yaw, rot_y
from training.data.skeleton import J

SEGMENT_SECONDS = 10.0


def segments(positions: np.ndarray, fps: float = 30.0, seconds: float = SEGMENT_SECONDS,
             min_fraction: float = 1.0) -> list[np.ndarray]:
  """Non-overlapping segments of `seconds` from the start; a shorter tail is kept only when it is at least
  min_fraction of a segment (default: dropped)."""
  n = int(round(seconds * fps))
  out = [positions[i:i + n] for i in range(0, len(positions) - n + 1, n)]
  tail = len(positions) % n
  if tail and tail >= min_fraction * n and min_fraction < 1.0:
    out.append(positions[-tail:])
  return out


def _rel(positions: np.ndarray) -> np.ndarray:
  p = np.asarray(positions, dtype=np.float64)
  rel = p - p[:, :1]
  rel[:, 0] = p[:, 0]
  return rel


def kinetic_features(positions: np.ndarray, fps: float = 30.0) -> np.ndarray:
  p = _rel(positions)
  v = np.diff(p, axis=0) * fps                    # (T-1, 24, 3)
  a = np.diff(v, axis=0) * fps                    # (T-2, 24, 3)
  ke_h = 0.5 * (v[..., 0] ** 2 + v[..., 2] ** 2).mean(0)
  ke_v = 0.5 * (v[..., 1] ** 2).mean(0)
  speed = np.linalg.norm(v, axis=-1)
  ee = (np.linalg.norm(a, axis=-1) * 0.5 * (speed[1:] + speed[:-1])).mean(0)
  return np.stack([ke_h, ke_v, ee], axis=-1).reshape(-1)


def _local(positions: np.ndarray) -> np.ndarray:
  """Positions in each frame's facing frame, pelvis at the origin horizontally (see representation.py)."""
  p = np.asarray(positions, dtype=np.float64)
  theta = facing_yaw(p)
  root = p[:, 0].copy()
  root[:, 1] = 0.0
  return np.einsum("tij,tnj->tni", rot_y(-theta), p - root[:, None])


def _angle(p, a, b, c):
  u = p[:, a] - p[:, b]
  w = p[:, c] - p[:, b]
  cos = (u * w).sum(-1) / (np.linalg.norm(u, axis=-1) * np.linalg.norm(w, axis=-1) + 1e-9)
  return np.arccos(np.clip(cos, -1, 1))


GEOMETRIC_NAMES = []


def _geometric_relations(positions: np.ndarray, fps: float) -> list[tuple[str, np.ndarray]]:
  p = np.asarray(positions, dtype=np.float64)
  loc = _local(p)
  v = np.gradient(p, axis=0) * fps
  speed = np.linalg.norm(v, axis=-1)
  yaw_rate = np.abs(np.gradient(np.unwrap(facing_yaw(p)))) * fps
  rel = []
  for side in ("left", "right"):
    hand, elbow, sh = J[f"{side}_wrist"], J[f"{side}_elbow"], J[f"{side}_shoulder"]
    foot, ankle, knee, hip = J[f"{side}_foot"], J[f"{side}_ankle"], J[f"{side}_knee"], J[f"{side}_hip"]
    s = 1.0 if side == "left" else -1.0
    rel += [
        (f"{side}_hand_above_head", loc[:, hand, 1] > loc[:, J["head"], 1]),
        (f"{side}_hand_above_shoulder", loc[:, hand, 1] > loc[:, sh, 1]),
        (f"{side}_hand_forward", loc[:, hand, 2] - loc[:, sh, 2] > 0.25),
        (f"{side}_hand_behind", loc[:, hand, 2] - loc[:, J["spine3"], 2] < -0.1),
        (f"{side}_hand_out_side", s * (loc[:, hand, 0] - loc[:, sh, 0]) > 0.3),
        (f"{side}_hand_crosses", s * (loc[:, hand, 0] - loc[:, J["spine3"], 0]) < 0.0),
        (f"{side}_elbow_bent", _angle(p, sh, elbow, hand) < 2.2),
        (f"{side}_hand_fast", speed[:, hand] > 1.5),
        (f"{side}_foot_raised", p[:, ankle, 1] - p[:, J["left_ankle" if side == "right" else
                                                     "right_ankle"], 1] > 0.08),
        (f"{side}_foot_forward", loc[:, ankle, 2] - loc[:, J["pelvis"], 2] > 0.2),
        (f"{side}_foot_behind", loc[:, ankle, 2] - loc[:, J["pelvis"], 2] < -0.2),
        (f"{side}_knee_bent", _angle(p, hip, knee, ankle) < 2.6),
        (f"{side}_foot_fast", speed[:, foot] > 1.0),
    ]
  rel += [
      ("feet_wide", np.abs(loc[:, J["left_ankle"], 0] - loc[:, J["right_ankle"], 0]) > 0.45),
      ("hands_far_apart", np.linalg.norm(p[:, J["left_wrist"]] - p[:, J["right_wrist"]], axis=-1) > 1.0),
      ("hands_close", np.linalg.norm(p[:, J["left_wrist"]] - p[:, J["right_wrist"]], axis=-1) < 0.3),
      ("lean_forward", loc[:, J["neck"], 2] - loc[:, J["pelvis"], 2] > 0.12),
      ("lean_back", loc[:, J["neck"], 2] - loc[:, J["pelvis"], 2] < -0.08),
      ("crouch", p[:, J["pelvis"], 1] < 0.8),
      ("travelling", np.linalg.norm(v[:, J["pelvis"], [0, 2]], axis=-1) > 0.5),
      ("turning", yaw_rate > 1.5),
  ]
  return rel


def geometric_features(positions: np.ndarray, fps: float = 30.0) -> np.ndarray:
  return np.array([r.mean() for _, r in _geometric_relations(positions, fps)], dtype=np.float64)


GEOMETRIC_NAMES.extend(n for n, _ in _geometric_relations(np.zeros((3, 24, 3)) +
                                                           np.arange(24)[None, :, None] * 0.01, 30.0))
