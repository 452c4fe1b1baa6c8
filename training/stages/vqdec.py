"""The vqdec stage: the decoders of <run>/vq_{part}.pt fine-tuned with the energy term
(training.common.decoder_tuning; --vq-dec-iters, --vq-energy-weight, --vq-dec-lr) into <run>/vqdec_{part}.pt
(a part already written is skipped). The encoders and codebooks, and so the codes, are unchanged. Writes
<run>/vqdec_report.json (the validation report of the fine-tuned pair; the stage is done when it exists).

Runs only for a run that trains its own VQ-VAEs: not with --vq-run or --vq-model, nor --vq-dec-iters 0.
"""
from __future__ import annotations

import json
import os
import time

import torch

from training.common import clips as td
from training.common.decoder_tuning import finetune_decoder, training_arrays
from training.common.run_dir import load_vqs
from training.common.vq_training import validation_report
from training.run_config import PARTS, RunConfig


def wanted(config: RunConfig) -> bool:
  return config.vq_dec_iters > 0 and not config.vq_run and not config.vq_model


def done(config: RunConfig) -> bool:
  return (config.run / "vqdec_report.json").is_file()


def run(config: RunConfig, log) -> dict:
  run_dir = config.run
  vqs = load_vqs(run_dir, fine_tuned=False)
  for part in PARTS:
    path = run_dir / f"vqdec_{part}.pt"
    if path.is_file():
      continue
    vq = vqs[part]
    t0 = time.time()
    hist = finetune_decoder(vq, part, training_arrays(part, config.vq_mirror), config.vq_dec_iters,
                            config.vq_energy_weight[part], lr=config.vq_dec_lr, log=log)
    tmp = path.with_suffix(".tmp")
    torch.save({"model": vq.state_dict(), "cfg": vq.cfg.to_dict(), "history": hist, "iter": config.vq_dec_iters,
                "finetune": {"energy_weight": config.vq_energy_weight[part], "lr": config.vq_dec_lr}}, tmp)
    os.replace(tmp, path)
    log(f"vqdec-{part}: {config.vq_dec_iters} iterations in {time.time() - t0:.0f} s -> {path}")
  val = [td.load_clip(i, with_music=False) for i in td.load_split()["validation"]]
  report = validation_report(load_vqs(run_dir), val)
  report["energy_weight"], report["iters"] = config.vq_energy_weight, config.vq_dec_iters
  log(f"vqdec validation: {json.dumps(report)}")
  (run_dir / "vqdec_report.json").write_text(json.dumps(report, indent=1))
  return report
