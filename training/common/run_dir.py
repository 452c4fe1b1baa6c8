"""A run directory's files and which of them belong together: the log, the VQ-VAE and sequence-model
checkpoints, and the owndec stage's decoders, which are valid only for the sequence model (and the
settings) whose own codes they were fitted to.

    log = Logger(run / "train.log")
    vqs = load_vqs(run)                       # vqdec_{part}.pt when fine-tuned, else vq_{part}.pt
    vqs = own_decoder(vqs, run, config)       # owndec_{part}.pt where it fits seq.pt and the settings
    model = load_seq(run)                     # seq.pt (its weight average when trained with --ema)

Files (training/README.md lists them all): vq_{upper,lower}.pt (the vq stage), vqdec_{part}.pt (the vqdec
stage: decoders fine-tuned, encoders and codebooks unchanged), seq.pt (the seq stage), owndec_{part}.pt,
owndec_report.json and own_dances/ (the owndec stage, each stamped with seq.pt's sha256 and its settings).
"""
from __future__ import annotations

import copy
import hashlib
import json
import pathlib
import shutil
import time

import torch

from training.common import run_meta
from training.model.config import SeqConfig, VQConfig
from training.model.danceba import Danceba
from training.model.vqvae import PoseVQVAE
from training.run_config import PARTS, RunConfig


class Logger:
  """Prints a timestamped line and appends it to `path` (a run's train.log)."""

  def __init__(self, path: pathlib.Path):
    self.path = path
    path.parent.mkdir(parents=True, exist_ok=True)

  def __call__(self, msg: str) -> None:
    line = f"{time.strftime('%H:%M:%S')} {msg}"
    print(line, flush=True)
    with open(self.path, "a") as f:
      f.write(line + "\n")


def load_vqs(run: pathlib.Path, fine_tuned: bool = True, own: bool = False) -> dict[str, PoseVQVAE]:
  """The run's VQ-VAEs; with fine_tuned, a part's vqdec_{part}.pt (decoder fine-tuned) when it exists; with
  own too, a part's owndec_{part}.pt when it was made for the run's current sequence model
  (own_decoder)."""
  vqs = {}
  for part in PARTS:
    path = run / f"vqdec_{part}.pt"
    ck = torch.load(path if fine_tuned and path.is_file() else run / f"vq_{part}.pt")
    vq = PoseVQVAE(VQConfig.from_dict(ck["cfg"]))
    vq.load_state_dict(ck["model"])
    vqs[part] = vq.eval()
  return own_decoder(vqs, run) if fine_tuned and own else vqs


def load_seq(run: pathlib.Path) -> Danceba:
  """The sequence model of <run>/seq.pt: the exponential average of the weights when training kept one
  (--ema), else the last weights; eval mode."""
  ck = torch.load(run / "seq.pt")
  model = Danceba(SeqConfig.from_dict(ck["cfg"]))
  model.load_state_dict(ck["ema"] if ck.get("ema") is not None else ck["model"])
  return model.eval()


def seq_digest(run: pathlib.Path) -> str | None:
  """sha256 of the run's sequence model checkpoint (None without one): the owndec stage's decoder is valid
  only for the model whose codes it was fine-tuned on."""
  path = run / "seq.pt"
  return hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() else None


def owndec_dance_settings(config: RunConfig, run: pathlib.Path) -> dict:
  """What the owndec stage's engine dances depend on besides the sequence model: the exported file's
  time_base and sampling metadata (period lock, style tempi, guidance) and the seeds."""
  return {"time_base": run_meta.time_base_meta(config, run, lambda *_: None),
          "sampling": run_meta.sampling_meta(config),
          "seeds": [int(s) for s in config.own_seeds]}


def owndec_finetune_settings(config: RunConfig) -> dict:
  """The owndec stage's fine-tuning options (recorded in its checkpoints and report)."""
  parts = config.own_parts()
  return {"iters": config.own_iters, "own_weight": {p: config.own_weight[p] for p in parts},
          "own_anchor": config.own_anchor, "energy_weight": {p: config.vq_energy_weight[p] for p in parts},
          "lr": config.vq_dec_lr, "seeds": [int(s) for s in config.own_seeds]}


def owndec_settings(config: RunConfig, run: pathlib.Path) -> dict:
  """What the owndec stage's decoder depends on besides the sequence model: its dances' settings and the
  fine-tuning's own."""
  return dict(owndec_dance_settings(config, run), **owndec_finetune_settings(config))


def _owndec_fits(saved: dict, run: pathlib.Path, config: RunConfig | None) -> bool:
  """A saved owndec report or checkpoint was made for the run's sequence model and, when a config is given,
  with the same settings (owndec_settings): a change of the sampling metadata or of --own-* redoes it."""
  if saved.get("seq_sha256") != seq_digest(run):
    return False
  return config is None or saved.get("settings") == json.loads(json.dumps(owndec_settings(config, run)))


def owndec_current(run: pathlib.Path, config: RunConfig | None = None) -> dict | None:
  """<run>/owndec_report.json when it was written for the run's current sequence model (and, with a config,
  the current settings: _owndec_fits), else None."""
  path = run / "owndec_report.json"
  if not path.is_file():
    return None
  report = json.loads(path.read_text())
  return report if _owndec_fits(report, run, config) else None


def own_decoder(vqs: dict, run: pathlib.Path, config: RunConfig | None = None) -> dict:
  """vqs with each part's decoder of <run>/owndec_{part}.pt when that file exists and was fine-tuned on the
  codes of the run's current sequence model (with a config: and the current settings); other parts
  unchanged."""
  out = dict(vqs)
  for part in PARTS:
    path = run / f"owndec_{part}.pt"
    if not path.is_file():
      continue
    ck = torch.load(path)
    if not _owndec_fits(ck, run, config):
      continue
    out[part] = copy.deepcopy(vqs[part])
    out[part].load_state_dict(ck["model"])
    out[part].eval()
  return out


def own_dances_dir(config: RunConfig, run: pathlib.Path) -> pathlib.Path:
  """<run>/own_dances/, emptied first when its dances were made by another sequence model or with other
  settings (owndec_dance_settings); stamped with the current ones in settings.key (not *.json:
  decoder_tuning.load_own_codes reads every JSON file there as a dance)."""
  dances = run / "own_dances"
  stamp = dances / "settings.key"
  key = json.dumps({"seq_sha256": seq_digest(run), **owndec_dance_settings(config, run)}, sort_keys=True)
  if dances.is_dir() and (not stamp.is_file() or stamp.read_text() != key):
    shutil.rmtree(dances)
  dances.mkdir(parents=True, exist_ok=True)
  stamp.write_text(key)
  return dances
