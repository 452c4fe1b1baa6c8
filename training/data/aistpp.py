"""Loader for the AIST++ layout: motions/*.pkl (SMPL parameters at 60 fps) and wavs/*.wav.

A motion file is a pickled dict with `smpl_poses` (T, 72) axis-angle per joint (SMPL order, radians),
`smpl_trans` (T, 3) and `smpl_scaling` (scalar or (1,)). AIST++ stores the translation in the scaled space,
so the pelvis position in metres is smpl_trans / smpl_scaling. Forward kinematics uses the canonical rest
offsets of ../shared/data/skeleton (no SMPL body model needed), so bone lengths are canonical by
construction. 60 fps -> 30 fps keeps every second frame (exact: no interpolation of rotations needed).

Usage:
  for motion_id, m in load_aistpp("/data/aist_plusplus_final"):
    ...   # m: sources.Motion at 30 fps
"""
from __future__ import annotations

import pathlib
import pickle
from collections.abc import Iterator

import numpy as np

from training.data import skeleton as sk
from training.data.sources import Motion

AIST_GENRES = {"BR": "break", "PO": "pop", "LO": "lock", "MH": "middle-hiphop", "LH": "la-hiphop",
               "HO": "house", "WA": "waack", "KR": "krump", "JS": "street-jazz", "JB": "ballet-jazz"}


def axis_angle_to_matrix(aa: np.ndarray) -> np.ndarray:
  """Rodrigues: (..., 3) axis-angle -> (..., 3, 3)."""
  angle = np.linalg.norm(aa, axis=-1, keepdims=True)
  axis = aa / np.maximum(angle, 1e-12)
  x, y, z = axis[..., 0], axis[..., 1], axis[..., 2]
  zero = np.zeros_like(x)
  k = np.stack([zero, -z, y, z, zero, -x, -y, x, zero], axis=-1).reshape(aa.shape[:-1] + (3, 3))
  s = np.sin(angle)[..., None]
  c = np.cos(angle)[..., None]
  eye = np.broadcast_to(np.eye(3), k.shape)
  return eye + s * k + (1 - c) * (k @ k)


def smpl_forward_kinematics(poses: np.ndarray, trans: np.ndarray, skel: sk.Skeleton) -> np.ndarray:
  """poses (T, 72) axis-angle, trans (T, 3) metres -> global joint positions (T, 24, 3).

  Global rotation G_j = G_parent @ R_j; position_j = position_parent + G_parent @ offset_j; the pelvis sits
  at trans (its rest offset is zero) and is rotated by R_0.
  """
  t = poses.shape[0]
  local = axis_angle_to_matrix(poses.reshape(t, 24, 3))
  glob = np.zeros((t, 24, 3, 3))
  pos = np.zeros((t, 24, 3))
  glob[:, 0] = local[:, 0]
  pos[:, 0] = trans + skel.offsets[0]
  for j in range(1, 24):
    p = skel.parents[j]
    glob[:, j] = glob[:, p] @ local[:, j]
    pos[:, j] = pos[:, p] + glob[:, p] @ skel.offsets[j]
  return pos


def load_aistpp_motion(pkl_path: str | pathlib.Path, skel: sk.Skeleton,
                       wav_dir: str | pathlib.Path | None = None) -> Motion:
  pkl_path = pathlib.Path(pkl_path)
  with open(pkl_path, "rb") as f:
    d = pickle.load(f)
  poses = np.asarray(d["smpl_poses"], dtype=np.float64)
  trans = np.asarray(d["smpl_trans"], dtype=np.float64)
  scaling = float(np.asarray(d.get("smpl_scaling", 1.0)).reshape(-1)[0])
  if poses.ndim != 2 or poses.shape[1] != 72 or trans.shape != (poses.shape[0], 3):
    raise ValueError(f"{pkl_path}: expected smpl_poses (T, 72) and smpl_trans (T, 3), got "
                     f"{poses.shape} and {trans.shape}")
  pos = smpl_forward_kinematics(poses[::2], trans[::2] / scaling, skel)   # 60 -> 30 fps
  pos = sk.put_on_floor(pos)
  # Names look like gBR_sBM_cAll_d04_mBR0_ch01: genre after 'g', music id after 'm'.
  parts = pkl_path.stem.split("_")
  genre = next((p[1:] for p in parts if p.startswith("g")), "")
  music = next((p for p in parts if p.startswith("m") and len(p) > 1), "")
  wav = ""
  if wav_dir is not None and music:
    wav = str(pathlib.Path(wav_dir) / f"{music}.wav")
  return Motion(pos.astype(np.float32), sk.FPS, AIST_GENRES.get(genre, genre or "unknown"), "aistpp",
                audio_path=wav, audio_offset_s=0.0, notes={"source_fps": 60, "scaling": scaling})


def load_aistpp(root: str | pathlib.Path, skel: sk.Skeleton | None = None,
                ignore: set[str] | None = None) -> Iterator[tuple[str, Motion]]:
  """Yields (id, Motion) for every root/motions/*.pkl not in `ignore` (AIST++'s ignore list names)."""
  root = pathlib.Path(root)
  skel = skel or sk.load_skeleton()
  ignore = ignore or set()
  for pkl in sorted((root / "motions").glob("*.pkl")):
    if pkl.stem in ignore:
      continue
    yield f"aist_{pkl.stem}", load_aistpp_motion(pkl, skel, root / "wavs")
