"""SGMD's weights file: a `.dncw` (docs/weights-format.md) of kind "sgmd" (docs/diffusion.md section 6).

    export_sgmd("models/sgmd.dncw", model, stats, styles, {"model_id": ...})
    model, stats, meta = load_sgmd("models/sgmd.dncw")
"""
from __future__ import annotations

import dataclasses

import numpy as np
import torch

from training.diffusion import motion
from training.diffusion.data import Stats
from training.export import f16_policy, read_dncw, write_dncw
from training.fixtures import FEATURES_META, skeleton_meta
from training.model.sgmd import SGMD, SGMDConfig

PREFIX = "sgmd."
MOTION_META = {"pose_dim": motion.POSE_DIM, "root": [0, 3], "heading": [3, 5], "local": [5, 74],
               "contact": [74, 78], "contact_joints": list(motion.FOOT_JOINTS),
               "contact_speed_m_s": motion.CONTACT_SPEED, "layout": "docs/diffusion.md section 2"}


def sgmd_tensors(model: SGMD, stats: Stats) -> dict[str, np.ndarray]:
  out = {PREFIX + k: v.detach().float().numpy() for k, v in model.state_dict().items()}
  out[PREFIX + "alphas_cumprod"] = model.alphas_cumprod.numpy().astype(np.float32)
  out[PREFIX + "pose_mean"] = stats.pose_mean.astype(np.float32)
  out[PREFIX + "pose_std"] = stats.pose_std.astype(np.float32)
  out[PREFIX + "music_mean"] = stats.music_mean.astype(np.float32)
  out[PREFIX + "music_std"] = stats.music_std.astype(np.float32)
  return out


def export_sgmd(path: str, model: SGMD, stats: Stats, styles: list[str], extra: dict,
                weights_dtype: str = "f16") -> dict:
  tensors = sgmd_tensors(model, stats)
  cfg = dataclasses.asdict(model.cfg)
  cfg.pop("dropout")
  meta = {"kind": "sgmd", "model_id": extra.get("model_id", "unnamed"), "sgmd": cfg, "features": FEATURES_META,
          "skeleton": skeleton_meta(), "styles": list(styles), "motion": MOTION_META,
          "sampling": {"steps": 50, "guidance": 1.0, "overlap_frames": cfg["frames"] // 2}}
  meta.update({k: v for k, v in extra.items() if k != "model_id"})
  keep = ("*alphas_cumprod", "*_mean", "*_std")
  dtypes = f16_policy(tensors) if weights_dtype == "f16" else {}
  for name in tensors:
    if any(name.endswith(k.lstrip("*")) for k in keep):
      dtypes[name] = "f32"
  write_dncw(path, tensors, meta, dtypes)
  return meta


def load_sgmd(path: str) -> tuple[SGMD, Stats, dict]:
  header, tensors = read_dncw(path)
  meta = header["metadata"]
  if meta.get("kind") != "sgmd":
    raise ValueError(f"{path}: not an SGMD model (kind {meta.get('kind')!r})")
  cfg = SGMDConfig(**meta["sgmd"], dropout=0.0)
  model = SGMD(cfg).eval()
  state = {k[len(PREFIX):]: torch.from_numpy(v) for k, v in tensors.items() if k.startswith(PREFIX)}
  stats = Stats(*(state.pop(n).numpy().astype(np.float64) for n in ("pose_mean", "pose_std", "music_mean", "music_std")))
  state.pop("alphas_cumprod")
  model.load_state_dict(state)
  return model, stats, meta
