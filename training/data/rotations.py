"""Per-joint local rotations from global positions (for BVH export and avatars); docs/rotations.md.

Quaternions are (w, x, y, z), unit, Hamilton product; a rotation q maps v to q v q*. Everything is float64
here; the engine reproduces the same steps in float32.

Usage:
  local_q = local_rotations(positions, skel)        # (T, 24, 4)
  pos = forward_kinematics(local_q, positions[:, 0], skel)
"""
from __future__ import annotations

import numpy as np

from training.data import skeleton as sk
from training.data.skeleton import J

# The child whose bone direction drives a joint with one child (shortest arc). Joints with several
# children (pelvis, spine3) use a full frame; leaves (feet, head, hands) copy their parent's rotation.
PRIMARY_CHILD = {J["left_hip"]: J["left_knee"], J["right_hip"]: J["right_knee"], J["spine1"]: J["spine2"],
                 J["left_knee"]: J["left_ankle"], J["right_knee"]: J["right_ankle"],
                 J["spine2"]: J["spine3"], J["left_ankle"]: J["left_foot"],
                 J["right_ankle"]: J["right_foot"], J["neck"]: J["head"],
                 J["left_collar"]: J["left_shoulder"], J["right_collar"]: J["right_shoulder"],
                 J["left_shoulder"]: J["left_elbow"], J["right_shoulder"]: J["right_elbow"],
                 J["left_elbow"]: J["left_wrist"], J["right_elbow"]: J["right_wrist"],
                 J["left_wrist"]: J["left_hand"], J["right_wrist"]: J["right_hand"]}
# Frame joints: (left point, right point, low point, high point) as in skeleton.body_frame.
FRAME_JOINTS = {J["pelvis"]: (J["left_hip"], J["right_hip"], J["pelvis"], J["spine1"]),
                J["spine3"]: (J["left_collar"], J["right_collar"], J["spine3"], J["neck"])}


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
  aw, ax, ay, az = np.moveaxis(a, -1, 0)
  bw, bx, by, bz = np.moveaxis(b, -1, 0)
  return np.stack([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                   aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw], -1)


def quat_conj(q: np.ndarray) -> np.ndarray:
  return q * np.array([1.0, -1.0, -1.0, -1.0])


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
  """Rotates vectors v (..., 3) by unit quaternions q (..., 4)."""
  w, u = q[..., :1], q[..., 1:]
  t = 2.0 * np.cross(u, v)
  return v + w * t + np.cross(u, t)


def quat_from_matrix(m: np.ndarray) -> np.ndarray:
  """(..., 3, 3) rotation matrices -> (..., 4) with w >= 0 (Shepperd's method, branch per element)."""
  m = np.asarray(m, dtype=np.float64)
  out = np.zeros(m.shape[:-2] + (4,))
  tr = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
  cands = [
      (tr, lambda s: [0.25 * s, (m[..., 2, 1] - m[..., 1, 2]) / s, (m[..., 0, 2] - m[..., 2, 0]) / s,
                      (m[..., 1, 0] - m[..., 0, 1]) / s], 1 + tr),
      (m[..., 0, 0], lambda s: [(m[..., 2, 1] - m[..., 1, 2]) / s, 0.25 * s,
                                (m[..., 0, 1] + m[..., 1, 0]) / s, (m[..., 0, 2] + m[..., 2, 0]) / s],
       1 + m[..., 0, 0] - m[..., 1, 1] - m[..., 2, 2]),
      (m[..., 1, 1], lambda s: [(m[..., 0, 2] - m[..., 2, 0]) / s, (m[..., 0, 1] + m[..., 1, 0]) / s,
                                0.25 * s, (m[..., 1, 2] + m[..., 2, 1]) / s],
       1 - m[..., 0, 0] + m[..., 1, 1] - m[..., 2, 2]),
      (m[..., 2, 2], lambda s: [(m[..., 1, 0] - m[..., 0, 1]) / s, (m[..., 0, 2] + m[..., 2, 0]) / s,
                                (m[..., 1, 2] + m[..., 2, 1]) / s, 0.25 * s],
       1 - m[..., 0, 0] - m[..., 1, 1] + m[..., 2, 2]),
  ]
  radicands = np.stack([c[2] for c in cands], -1)
  best = radicands.argmax(-1)
  for k, (_, f, rad) in enumerate(cands):
    sel = best == k
    if np.any(sel):
      s = 2.0 * np.sqrt(np.maximum(rad, 1e-12))
      q = np.stack(f(s), -1)
      out[sel] = q[sel]
  out *= np.where(out[..., :1] < 0, -1.0, 1.0)
  return out / np.linalg.norm(out, axis=-1, keepdims=True)


def shortest_arc(a: np.ndarray, b: np.ndarray) -> np.ndarray:
  """Unit quaternion of the smallest rotation taking direction a to direction b (..., 3)."""
  a = a / np.linalg.norm(a, axis=-1, keepdims=True)
  b = b / np.linalg.norm(b, axis=-1, keepdims=True)
  d = (a * b).sum(-1, keepdims=True)
  c = np.cross(a, b)
  q = np.concatenate([1.0 + d, c], axis=-1)
  # Opposite directions: rotate by pi about an axis orthogonal to a (a x X, or a x Y if a is along X).
  opp = d[..., 0] < -1.0 + 1e-9
  if np.any(opp):
    ao = a[opp]
    axis = np.cross(ao, np.array([1.0, 0.0, 0.0]))
    small = np.linalg.norm(axis, axis=-1) < 1e-6
    axis[small] = np.cross(ao[small], np.array([0.0, 1.0, 0.0]))
    q[opp] = np.concatenate([np.zeros((len(ao), 1)), axis], axis=-1)
  return q / np.linalg.norm(q, axis=-1, keepdims=True)


def global_rotations(positions: np.ndarray, skel: sk.Skeleton) -> np.ndarray:
  """(T, 24, 3) -> global joint rotations (T, 24, 4), walking the tree from the pelvis."""
  p = np.asarray(positions, dtype=np.float64)
  rest = skel.rest_positions()
  g = np.zeros(p.shape[:-2] + (24, 4))
  for j in range(24):
    parent = skel.parents[j]
    if j in FRAME_JOINTS:
      l, r, lo, hi = FRAME_JOINTS[j]
      posed = sk.body_frame(p[..., l, :], p[..., r, :], p[..., lo, :], p[..., hi, :])
      rest_f = sk.body_frame(rest[l], rest[r], rest[lo], rest[hi])
      g[..., j, :] = quat_from_matrix(posed @ rest_f.T)
    elif j in PRIMARY_CHILD:
      c = PRIMARY_CHILD[j]
      a = quat_rotate(g[..., parent, :], np.broadcast_to(skel.offsets[c], p[..., c, :].shape))
      g[..., j, :] = quat_mul(shortest_arc(a, p[..., c, :] - p[..., j, :]), g[..., parent, :])
    else:
      g[..., j, :] = g[..., parent, :]
  return g


def local_rotations(positions: np.ndarray, skel: sk.Skeleton) -> np.ndarray:
  """Local rotations (T, 24, 4): local_j = conj(global_parent) * global_j; the pelvis's is its global."""
  g = global_rotations(positions, skel)
  out = g.copy()
  for j in range(1, 24):
    out[..., j, :] = quat_mul(quat_conj(g[..., skel.parents[j], :]), g[..., j, :])
  return out * np.where(out[..., :1] < 0, -1.0, 1.0)


def forward_kinematics(local_q: np.ndarray, root: np.ndarray, skel: sk.Skeleton) -> np.ndarray:
  """Local rotations (T, 24, 4) + pelvis positions (T, 3) -> positions (T, 24, 3) on the rest offsets."""
  g = np.zeros_like(local_q)
  pos = np.zeros(local_q.shape[:-1] + (3,))
  g[..., 0, :] = local_q[..., 0, :]
  pos[..., 0, :] = root
  for j in range(1, 24):
    p = skel.parents[j]
    g[..., j, :] = quat_mul(g[..., p, :], local_q[..., j, :])
    pos[..., j, :] = pos[..., p, :] + quat_rotate(g[..., p, :], np.broadcast_to(skel.offsets[j],
                                                                                 pos[..., j, :].shape))
  return pos
