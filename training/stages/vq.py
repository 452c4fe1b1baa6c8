"""The vq stage: both pose VQ-VAEs (upper body 45 channels, lower body 31) trained on split.json's training
motion (training.common.vq_training), then their reconstruction of the validation dances.

Writes <run>/vq_{upper,lower}.pt (resumable checkpoints), vq_{part}_history.json (the curves) and
vq_report.json (the stage is done when it exists). Removes the vqdec stage's outputs: decoders fine-tuned
from earlier VQ-VAEs would not match the new codebooks.
"""
from __future__ import annotations

import json

from training.common import clips as td
from training.common.vq_training import train_vq, training_clips, validation_report
from training.model.config import VQConfig
from training.run_config import RunConfig

PART_DIMS = (("upper", 45), ("lower", 31))


def done(config: RunConfig) -> bool:
  return (config.run / "vq_report.json").is_file()


def run(config: RunConfig, log) -> dict:
  run_dir = config.run
  # Decoders fine-tuned from an earlier VQ-VAE would not match the new codebooks: the vqdec stage redoes them.
  for stale in ("vqdec_upper.pt", "vqdec_lower.pt", "vqdec_report.json"):
    (run_dir / stale).unlink(missing_ok=True)
  train = training_clips(config.vq_mirror)
  val = [td.load_clip(i, with_music=False) for i in td.load_split()["validation"]]
  log(f"vq: {len(train)} train clips ({sum(len(c.upper) for c in train)} frames), {len(val)} validation")
  vqs = {}
  for part, dim in PART_DIMS:
    cfg = VQConfig(in_dim=dim, width=config.vq_width, code_dim=config.vq_code_dim,
                   codebook_size=config.codebook_size, path_weight=config.vq_path_weight,
                   vel_weight=config.vq_vel_weight, acc_weight=config.vq_acc_weight)
    arrays = [getattr(c, part) for c in train]
    vqs[part], hist = train_vq(part, arrays, cfg, config.vq_iters, run_dir / f"vq_{part}.pt", log)
    (run_dir / f"vq_{part}_history.json").write_text(json.dumps(hist))
  report = validation_report(vqs, val)
  log(f"vq validation: {json.dumps(report)}")
  (run_dir / "vq_report.json").write_text(json.dumps(report, indent=1))
  return report
