"""The pose VQ-VAEs' ceiling: the metric table of the real validation dances encoded and decoded by a model's
VQ-VAEs (no sequence model), beside the real dances and the baselines. A generated dance can hardly score
better than these reconstructions.

    .venv/bin/python -m training.experiments.vq_recon [--model models/default.dncw] [--lower-ckpt RUN/vq_lower.pt]
        [--upper-ckpt RUN/vq_upper.pt]

`--lower-ckpt` / `--upper-ckpt` swap in a VQ-VAE checkpoint from training (the vq stage's vq_{part}.pt,
training.experiments.vq_decoder's) to compare it against the file's. Decoding: rep.decode from the real first
frame's heading and root, then the canonical bone lengths (as the engine). Needs librosa's beat cache (the
project .venv) for BAS.
"""
from __future__ import annotations

import argparse
import pathlib

import numpy as np
import torch

from training.common import clips as td
from training.common.vq_training import reconstruct
from training.data import representation as rep
from training.data import skeleton as sk
from training.eval.evaluate import Dance, Evaluator, markdown_table
from training.export import load_models
from training.model.config import VQConfig
from training.model.vqvae import PoseVQVAE

REPO = pathlib.Path(__file__).resolve().parents[2]


def reconstructed(vqs, validation):
  skel = sk.load_skeleton()
  out = []
  for d in validation:
    c = td.load_clip(d.name, with_music=False)
    ru, _ = reconstruct(vqs["upper"], c.upper)
    rl, _ = reconstruct(vqs["lower"], c.lower)
    real = c.positions[:len(ru)].astype(np.float64)
    pos = rep.decode(ru, rl, theta_init=float(rep.facing_yaw(real[:1])[0]), root_init=(real[0, 0, 0], real[0, 0, 2]))
    out.append(Dance(d.name, sk.project_bone_lengths(pos, skel), 30.0, d.audio_path, d.audio_offset_s, d.style))
  return out


def main(argv=None) -> None:
  ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  ap.add_argument("--model", default=str(REPO / "models" / "default.dncw"))
  ap.add_argument("--lower-ckpt", default=None, help="a vq stage checkpoint to use for the lower body")
  ap.add_argument("--upper-ckpt", default=None, help="a vq stage checkpoint to use for the upper body")
  args = ap.parse_args(argv)
  _, vqs, _ = load_models(args.model)
  for part, path in (("lower", args.lower_ckpt), ("upper", args.upper_ckpt)):
    if path:
      ck = torch.load(path)
      vq = PoseVQVAE(VQConfig.from_dict(ck["cfg"]))
      vq.load_state_dict(ck["model"])
      vqs[part] = vq.eval()
  ev = Evaluator.default()
  rows = {"VQ-VAE reconstruction": ev.evaluate(reconstructed(vqs, ev.validation))}
  rows.update(ev.baselines())
  print(markdown_table(rows))


if __name__ == "__main__":
  main()
