"""The owndec stage: the decoders fine-tuned on the sequence model's own codes
(training.common.decoder_tuning.OwnCodes). The exported model (config.out) dances every Tang training song in
its own style through the engine (`dance-generate`, seeds --own-seeds) into <run>/own_dances/, then each part
with an --own-weight above 0 has its decoder fine-tuned, from the same dances, with the vqdec stage's loss (its
energy weight of the part) plus the part's --own-weight x the own-codes term. Writes <run>/owndec_{part}.pt and
owndec_report.json, all keyed to the sequence model (run_dir.seq_digest) and the settings
(run_dir.owndec_settings): a retrained model or other sampling metadata redoes the stage. The caller exports
again with the new decoders.
"""
from __future__ import annotations

import copy
import json
import os
import time

import torch

from training import tools
from training.common import clips as td
from training.common import run_dir as rd
from training.common.decoder_tuning import finetune_decoder, training_arrays
from training.common.vq_training import validation_report
from training.eval.engine_eval import generate_song
from training.run_config import RunConfig


def wanted(config: RunConfig) -> bool:
  """Only tempo-normalised runs with --own-iters > 0 and a part whose --own-weight is above 0."""
  return bool(config.own_iters > 0 and config.own_parts() and config.tempo_ref > 0)


def done(config: RunConfig) -> bool:
  return rd.owndec_current(config.run, config) is not None


def run(config: RunConfig, vqs: dict, log) -> dict:
  """Returns vqs with the fitted parts' new decoders (vqs: the run's VQ-VAEs before this stage)."""
  try:
    tools.require("dance-generate")
  except tools.ToolMissing as e:
    raise SystemExit(f"owndec: {e}") from None
  run_dir = config.run
  digest = rd.seq_digest(run_dir)
  dances = rd.own_dances_dir(config, run_dir)
  ids = td.tang_ids(td.load_split()["train"])
  t0 = time.time()
  for seed in config.own_seeds:
    for mid in ids:
      out = dances / f"{mid}_s{seed}.json"
      if not out.is_file():
        tmp = dances / f"{mid}_s{seed}.tmp.json"
        generate_song(str(config.out), mid, tmp, seed, 1.0)
        os.replace(tmp, out)
  log(f"owndec: {len(ids)} training songs x {len(config.own_seeds)} seeds danced by the engine in "
      f"{time.time() - t0:.0f} s -> {dances}")
  settings = rd.owndec_finetune_settings(config)
  full = json.loads(json.dumps(rd.owndec_settings(config, run_dir)))
  new, last = dict(vqs), {}
  for part in config.own_parts():
    vq = copy.deepcopy(vqs[part])
    t0 = time.time()
    hist = finetune_decoder(vq, part, training_arrays(part, config.vq_mirror), config.own_iters,
                            config.vq_energy_weight[part], lr=config.vq_dec_lr, log=log, own_dances=str(dances),
                            own_weight=config.own_weight[part], own_anchor=config.own_anchor)
    path = run_dir / f"owndec_{part}.pt"
    tmp = path.with_suffix(".tmp")
    torch.save({"model": vq.state_dict(), "cfg": vq.cfg.to_dict(), "history": hist, "iter": config.own_iters,
                "finetune": settings, "seq_sha256": digest, "settings": full}, tmp)
    os.replace(tmp, path)
    log(f"owndec-{part}: {config.own_iters} iterations in {time.time() - t0:.0f} s -> {path}")
    new[part] = vq
    last[part] = hist[-1] if hist else None
  val = [td.load_clip(i, with_music=False) for i in td.load_split()["validation"]]
  report = dict(validation_report(new, val), **settings, seq_sha256=digest, settings=full, last=last)
  log(f"owndec validation: {json.dumps(report)}")
  (run_dir / "owndec_report.json").write_text(json.dumps(report, indent=1))
  return new
