"""Decoder-only fine-tuning of a model's pose VQ-VAEs, with an energy-matching term (an experiment).

    OMP_WAIT_POLICY=PASSIVE .venv/bin/python -m training.train_vq_decoder --model models/default.dncw \
        --iters 1500 --energy-weight 1 --out /tmp/vqdec/e1
    .venv/bin/python -m training.eval.vq_recon --upper-ckpt /tmp/vqdec/e1/vq_upper.pt \
        --lower-ckpt /tmp/vqdec/e1/vq_lower.pt

The encoders and codebooks stay frozen (eval mode: the EMA codebook is not updated), so every code, and the
sequence model trained on the codes, stays valid; only the causal decoders change. Loss per window:
train_vq.vq_loss (the shipped recipe's reconstruction, velocity and acceleration terms; the commitment term
is a constant here) plus `energy_weight` x `energy_loss`: per joint (the three position channels of a joint
together; the lower body's four root channels one by one), in metres, the window's mean squared velocity
and mean |acceleration| of the decoded motion against the real window's, as squared log-ratios. An L2-type
decoder outputs about the conditional mean of the motion given the codes and so loses energy (docs/training.md,
"Why FID_k stays ~20"); the energy term asks each window to keep its real energy.

Writes <out>/vq_upper.pt and <out>/vq_lower.pt in train_vq's checkpoint format ("model", "cfg", "history",
"iter"), which training.eval.vq_recon --upper-ckpt / --lower-ckpt read. With --export FILE it also writes
the model file with the fine-tuned decoders: every other tensor and the metadata as in --model (the
fine-tuning recorded under training.vqdec), f16 like the shipped file; the one command's `vqdec` stage
(training.train) does the same inside a training run.
"""
from __future__ import annotations

import argparse
import json
import math
import pathlib
import time

import numpy as np
import torch
from tqdm import tqdm

from training.model.vqvae import PoseVQVAE
from training.train_vq import sample_windows, vq_loss

PARTS = ("upper", "lower")
# The energy statistics leave out each window's first frames: the causal decoder starts a window from zero
# state, and its error there is 1.5-2.8x the rest of the window's (measured on the shipped file; the error
# settles after about 16 frames), a transient the whole-sequence decode (and the engine) does not have.
ENERGY_SKIP = 16


def channel_groups(in_dim: int) -> list[list[int]]:
  """Channels taken together by the energy term: each joint's (x, y, z); the lower body's root channels
  (vx, vz, yaw rate, height: 31 = 9 joints x 3 + 4) one by one."""
  n_joints = in_dim // 3 if in_dim % 3 == 0 else (in_dim - 4) // 3
  groups = [[3 * j, 3 * j + 1, 3 * j + 2] for j in range(n_joints)]
  return groups + [[c] for c in range(3 * n_joints, in_dim)]


def window_energy(x: torch.Tensor, groups: list[list[int]]) -> torch.Tensor:
  """x (B, T, dim) denormalised -> (B, G, 2): per group, the window's mean squared velocity (sum over the
  group's channels) and mean |acceleration| (Euclidean over the group's channels), per frame units."""
  v = x[:, 1:] - x[:, :-1]
  a = x[:, 2:] - 2 * x[:, 1:-1] + x[:, :-2]
  out = []
  for g in groups:
    ke = v[..., g].pow(2).sum(-1).mean(1)
    acc = (a[..., g].pow(2).sum(-1) + 1e-12).sqrt().mean(1)
    out.append(torch.stack([ke, acc], dim=-1))
  return torch.stack(out, dim=1)


def energy_loss(decoded: torch.Tensor, target: torch.Tensor, groups: list[list[int]],
                eps: torch.Tensor | float = 1e-8, skip: int = ENERGY_SKIP) -> torch.Tensor:
  """Mean squared log-ratio of the windows' energy statistics (window_energy) decoded vs target, over the
  frames after the first `skip`; 0 when decoded == target. `eps` (scalar or (G, 2)) keeps near-still channels
  from dominating: set it to a small fraction of each statistic's typical value."""
  e_dec = window_energy(decoded[:, skip:], groups)
  e_tgt = window_energy(target[:, skip:], groups)
  return (torch.log(e_dec + eps) - torch.log(e_tgt + eps)).pow(2).mean()


def freeze_all_but_decoder(vq: PoseVQVAE) -> list[torch.nn.Parameter]:
  """Eval mode (no EMA codebook updates), requires_grad only on the decoder; returns the decoder's
  parameters."""
  vq.eval()
  for p in vq.parameters():
    p.requires_grad_(False)
  params = list(vq.decoder.parameters())
  for p in params:
    p.requires_grad_(True)
  return params


def decoder_step(vq: PoseVQVAE, opt: torch.optim.Optimizer, params, x: torch.Tensor, part: str,
                 energy_weight: float, groups, eps) -> dict:
  """One optimisation step on windows x (B, T, dim) (raw features). Returns the logged terms."""
  captured = {}
  hook = vq.decoder.register_forward_hook(lambda m, inp, out: captured.__setitem__("recon", out))
  try:
    loss, logs = vq_loss(vq, x, part)  # vq.eval(): the quantizer does not update its codebook
  finally:
    hook.remove()
  e = energy_loss(vq.denormalise(captured["recon"]), x, groups, eps)
  total = loss + energy_weight * e
  opt.zero_grad()
  total.backward()
  torch.nn.utils.clip_grad_norm_(params, 1.0)
  opt.step()
  logs.update(energy=float(e), loss=float(total))
  return logs


def energy_eps(arrays: list[np.ndarray], groups, rng: np.random.Generator, frac: float = 0.01) -> torch.Tensor:
  """(G, 2): `frac` x each statistic's mean over 32 x 8 training windows."""
  with torch.no_grad():
    e = torch.cat([window_energy(sample_windows(arrays, 32, rng)[:, ENERGY_SKIP:], groups) for _ in range(8)])
  return frac * e.mean(0)


def finetune_decoder(vq: PoseVQVAE, part: str, arrays: list[np.ndarray], iters: int, energy_weight: float,
                     lr: float = 1e-4, batch: int = 32, seed: int = 0, log=print,
                     log_every: int = 100) -> list[dict]:
  """Fine-tunes vq.decoder in place (cosine decay to 0.1 lr, as train_vq); returns the loss history."""
  torch.manual_seed(seed)
  rng = np.random.default_rng(seed)
  params = freeze_all_but_decoder(vq)
  groups = channel_groups(vq.cfg.in_dim)
  eps = energy_eps(arrays, groups, np.random.default_rng(seed + 1))
  opt = torch.optim.AdamW(params, lr=lr, weight_decay=0.0)
  history, t0, acc = [], time.time(), {}
  for it in tqdm(range(iters), desc=f"vqdec-{part}", mininterval=10):
    for g in opt.param_groups:
      g["lr"] = lr * (0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * it / iters)))
    logs = decoder_step(vq, opt, params, sample_windows(arrays, batch, rng), part, energy_weight, groups, eps)
    for k, v in logs.items():
      acc[k] = acc.get(k, 0.0) + v
    if (it + 1) % log_every == 0 or it == iters - 1:
      n = log_every if (it + 1) % log_every == 0 else (it + 1) % log_every
      mean = {k: round(v / n, 5) for k, v in acc.items()}
      history.append(dict(mean, iter=it + 1))
      log(f"vqdec-{part} iter {it + 1}/{iters} {mean} ({time.time() - t0:.0f} s)")
      acc = {}
  vq.eval()
  return history


def training_arrays(part: str, mirror: bool = False) -> list[np.ndarray]:
  """The VQ stage's training motion of `part` (train_vq.training_clips: split.json's "train", optionally
  mirrored; the shipped model: not mirrored)."""
  from training.train_vq import training_clips
  return [getattr(c, part) for c in training_clips(mirror)]


def main(argv=None) -> int:
  ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  ap.add_argument("--model", default="models/default.dncw", help="the .dncw file whose VQ-VAEs to fine-tune")
  ap.add_argument("--iters", type=int, default=1500, help="iterations per part")
  ap.add_argument("--energy-weight", type=float, default=1.0)
  ap.add_argument("--lr", type=float, default=1e-4)
  ap.add_argument("--batch", type=int, default=32)
  ap.add_argument("--seed", type=int, default=0)
  ap.add_argument("--parts", default="upper,lower")
  ap.add_argument("--mirror", action="store_true", help="also the mirrored training motion (as --vq-mirror)")
  ap.add_argument("--threads", type=int, default=1)
  ap.add_argument("--out", required=True, help="directory for vq_upper.pt / vq_lower.pt")
  ap.add_argument("--export", default=None, help="also write the model file with the fine-tuned decoders here")
  ap.add_argument("--model-id", default=None, help="--export: the new file's model id (default: --model's)")
  args = ap.parse_args(argv)
  torch.set_num_threads(args.threads)
  from training.export import load_models
  seq, vqs, meta = load_models(args.model)
  out = pathlib.Path(args.out)
  out.mkdir(parents=True, exist_ok=True)
  for part in args.parts.split(","):
    t0 = time.time()
    vq = vqs[part]
    hist = finetune_decoder(vq, part, training_arrays(part, args.mirror), args.iters, args.energy_weight,
                            lr=args.lr, batch=args.batch, seed=args.seed)
    torch.save({"model": vq.state_dict(), "cfg": vq.cfg.to_dict(), "history": hist, "iter": args.iters,
                "finetune": {k: v for k, v in vars(args).items()}}, out / f"vq_{part}.pt")
    print(f"vqdec-{part}: {args.iters} iterations in {time.time() - t0:.0f} s -> {out / f'vq_{part}.pt'}",
          flush=True)
  (out / "args.json").write_text(json.dumps(vars(args), indent=1))
  if args.export:
    export_with_decoders(args.export, seq, vqs, meta, vars(args), args.model_id)
    print(f"vqdec: wrote {args.export}", flush=True)
  return 0


def export_with_decoders(path: str, seq, vqs: dict[str, PoseVQVAE], meta: dict, finetune: dict,
                         model_id: str | None = None) -> None:
  """Writes `path`: the sequence model and VQ-VAEs given (decoders fine-tuned), metadata `meta` with the
  fine-tuning under training.vqdec and the model id replaced if given; big matrices f16 (export.f16_policy).
  Atomic: a failed write leaves an existing file (even the source model) intact."""
  import os

  from training.export import export_model
  extra = json.loads(json.dumps(meta))
  if model_id:
    extra["model_id"] = model_id
  extra.setdefault("training", {})["vqdec"] = {k: v for k, v in finetune.items() if k not in ("export", "model_id")}
  tmp = f"{path}.tmp.dncw"
  export_model(tmp, seq, vqs, extra, weights_dtype="f16")
  os.replace(tmp, path)


if __name__ == "__main__":
  raise SystemExit(main())
