"""The pose representation of docs/model.md section 7: encode positions, decode (root integration) exactly.

Conventions: positions (T, 24, 3) metres, Y up, SMPL order; the rest pose faces +Z with its left at +X.
  across  = (left_hip - right_hip) + (left_shoulder - right_shoulder), with y set to 0
  forward = normalize(across x up)          (up = +Y; the rest pose gives +Z)
  theta   = atan2(forward.x, forward.z)     (yaw about +Y; R_y(theta) maps +Z onto forward)
  R_y(a)  = [[cos a, 0, sin a], [0, 1, 0], [-sin a, 0, cos a]]
  local   = R_y(-theta) (J - (pelvis.x, 0, pelvis.z))      (pelvis row becomes (0, h, 0))
Upper (45): local[j] - local[pelvis] for j in UPPER_JOINTS, joint-major (x, y, z).
Lower (31): for j in LOWER_JOINTS: local[j] - local[pelvis], except the pelvis row which is (0, h, 0) (27);
  then vx, vz (m/frame, facing frame of the current frame), yaw rate (rad/frame), h (m):
  v_n = R_y(-theta_n) (root_xz_n - root_xz_{n-1}),  yaw_rate_n = wrap(theta_n - theta_{n-1}) in (-pi, pi],
  and for n = 0 both are 0.
Decode: theta_n = theta_{n-1} + yaw_rate_n, root_xz_n = root_xz_{n-1} + R_y(theta_n) (vx, 0, vz), starting
  from (theta_init, root_init) (default 0 and the origin: frame 0 at the origin facing +Z); the pelvis is at
  root_xz_n + (0, h_n, 0) with h_n = lower[..., 30] (the height channel; the pelvis row's copy is ignored);
  every other joint j: R_y(theta_n) part[j] + pelvis.

Usage:
  upper, lower = encode(positions)                     # (T, 45), (T, 31)
  pos = decode(upper, lower, theta_init=theta[0], root_init=pos[0, 0, [0, 2]])
"""
from __future__ import annotations

import numpy as np

from training.data.skeleton import J, LOWER_JOINTS, UPPER_JOINTS

UPPER_DIM = 45
LOWER_DIM = 31
ROOT_VX, ROOT_VZ, ROOT_YAW_RATE, ROOT_HEIGHT = 27, 28, 29, 30


def rot_y(theta: np.ndarray) -> np.ndarray:
  """(...,) angles -> (..., 3, 3) rotations about +Y."""
  c, s = np.cos(theta), np.sin(theta)
  z, o = np.zeros_like(theta), np.ones_like(theta)
  return np.stack([c, z, s, z, o, z, -s, z, c], axis=-1).reshape(np.shape(theta) + (3, 3))


def wrap_angle(a: np.ndarray) -> np.ndarray:
  """Wraps to (-pi, pi]."""
  return np.pi - np.mod(np.pi - a, 2 * np.pi)


def facing_yaw(positions: np.ndarray) -> np.ndarray:
  """(..., 24, 3) -> (...,) yaw of the body's forward direction (0 = facing +Z)."""
  p = np.asarray(positions, dtype=np.float64)
  across = (p[..., J["left_hip"], :] - p[..., J["right_hip"], :] +
            p[..., J["left_shoulder"], :] - p[..., J["right_shoulder"], :])
  # forward = across x up with up = (0, 1, 0): (ax, ay, az) x (0, 1, 0) = (-az, 0, ax)
  fx, fz = -across[..., 2], across[..., 0]
  return np.arctan2(fx, fz)


def encode(positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
  """positions (T, 24, 3) -> upper (T, 45), lower (T, 31), float64."""
  p = np.asarray(positions, dtype=np.float64)
  t = p.shape[0]
  theta = facing_yaw(p)
  root_xz = p[:, 0, :].copy()
  root_xz[:, 1] = 0.0
  inv = rot_y(-theta)                                          # (T, 3, 3)
  local = np.einsum("tij,tnj->tni", inv, p - root_xz[:, None])  # (T, 24, 3)
  rel = local - local[:, :1]
  height = local[:, 0, 1]
  upper = rel[:, list(UPPER_JOINTS)].reshape(t, UPPER_DIM)
  low = rel[:, list(LOWER_JOINTS)].copy()
  low[:, 0] = np.stack([np.zeros(t), height, np.zeros(t)], axis=-1)
  vel = np.zeros((t, 3))
  vel[1:] = np.einsum("tij,tj->ti", inv[1:], root_xz[1:] - root_xz[:-1])
  yaw_rate = np.zeros(t)
  yaw_rate[1:] = wrap_angle(theta[1:] - theta[:-1])
  lower = np.concatenate([low.reshape(t, 27), vel[:, [0]], vel[:, [2]], yaw_rate[:, None],
                          height[:, None]], axis=-1)
  return upper, lower


def integrate_root(lower: np.ndarray, theta_init: float = 0.0,
                   root_init=(0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
  """Integrates the root channels: returns theta (T,) and root_xz (T, 3) with y = 0."""
  lower = np.asarray(lower, dtype=np.float64)
  theta = theta_init + np.cumsum(lower[:, ROOT_YAW_RATE])
  v = np.stack([lower[:, ROOT_VX], np.zeros(len(lower)), lower[:, ROOT_VZ]], axis=-1)
  step = np.einsum("tij,tj->ti", rot_y(theta), v)
  root = np.cumsum(step, axis=0)
  root[:, 0] += root_init[0]
  root[:, 2] += root_init[1]
  return theta, root


def decode(upper: np.ndarray, lower: np.ndarray, theta_init: float = 0.0,
           root_init=(0.0, 0.0)) -> np.ndarray:
  """upper (T, 45), lower (T, 31) -> global positions (T, 24, 3); the exact inverse of `encode` given the
  first frame's yaw and root (x, z)."""
  upper = np.asarray(upper, dtype=np.float64)
  lower = np.asarray(lower, dtype=np.float64)
  t = upper.shape[0]
  theta, root = integrate_root(lower, theta_init, root_init)
  rel = np.zeros((t, 24, 3))
  rel[:, list(UPPER_JOINTS)] = upper.reshape(t, 15, 3)
  rel[:, list(LOWER_JOINTS)] = lower[:, :27].reshape(t, 9, 3)
  rel[:, 0] = 0.0
  pelvis = root + np.stack([np.zeros(t), lower[:, ROOT_HEIGHT], np.zeros(t)], axis=-1)
  return np.einsum("tij,tnj->tni", rot_y(theta), rel) + pelvis[:, None]


def heading_and_path_drift(real: np.ndarray, recon: np.ndarray) -> dict:
  """Heading error (degrees) and root position error (m) of `recon` against `real` at the last frame and
  at their worst; both (T, 24, 3). For the VQ-VAE's drift report (design section 6)."""
  dh = np.degrees(np.abs(wrap_angle(facing_yaw(recon) - facing_yaw(real))))
  dp = np.linalg.norm((recon[:, 0] - real[:, 0])[:, [0, 2]], axis=-1)
  return {"heading_deg_end": float(dh[-1]), "heading_deg_max": float(dh.max()),
          "path_m_end": float(dp[-1]), "path_m_max": float(dp.max())}
