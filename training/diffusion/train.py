"""Trains SGMD, the motion-diffusion editor, on the paired dances (CPU; docs/diffusion.md, docs/training.md).

    OMP_WAIT_POLICY=PASSIVE /usr/bin/python3 -m training.diffusion.train          # -> models/sgmd.dncw

Run directory (--run, default training/runs/sgmd/): train.log, sgmd_ckpt.pt (every --ckpt-every iterations;
the same command resumes from it exactly: model, EMA, optimiser, batch sampler and torch random states),
history.json and training_sgmd.png (the curves). At the end the EMA weights are exported (--out).
The loss (the paper's eq. 7): L_d (x0 prediction, normalised units; for a v model (--prediction v)
the v error, x0's divided by sqrt(1 - abar_t)) + L_v (frame differences of x0) +
lambda_j L_j (world joint positions, m^2) + lambda_f L_f (squared foot displacement per frame, m^2, where the
model predicts contact), weighted as EDGE's (the auxiliary terms stay small beside L_d). Music is dropped with --music-dropout (classifier-free
guidance), the style with --style-dropout (the "none" row).
"""
from __future__ import annotations

import argparse
import copy
import json
import math
import pathlib
import time

import numpy as np
import torch

from training.common import clips as td
from training.common.run_dir import Logger
from training.diffusion import motion
from training.diffusion.data import WindowData, Stats
from training.diffusion.export import export_sgmd
from training.model.sgmd import SGMD, SGMDConfig

FOOT = [7, 8, 10, 11]


def world_positions(v: torch.Tensor) -> torch.Tensor:
  """Denormalised motion vectors (B, N, 78) -> joint positions (B, N, 24, 3) in the window's frame."""
  theta = torch.atan2(v[..., 3], v[..., 4])
  c, s = torch.cos(theta)[..., None], torch.sin(theta)[..., None]
  rel = v[..., motion.LOCAL].reshape(*v.shape[:-1], 23, 3)
  x = c * rel[..., 0] + s * rel[..., 2]
  z = -s * rel[..., 0] + c * rel[..., 2]
  rel = torch.stack([x, rel[..., 1], z], dim=-1)
  rel = torch.cat([torch.zeros_like(rel[..., :1, :]), rel], dim=-2)
  return rel + v[..., None, motion.ROOT]


def losses(pred: torch.Tensor, x0: torch.Tensor, mean: torch.Tensor, std: torch.Tensor,
           noise_std: torch.Tensor | None = None) -> dict:
  """pred, x0: (B, N, D) normalised. noise_std (B,): sqrt(1 - abar_t) of each sample for a v model, whose L_d is
  the v error ((x0_hat - x0) / sqrt(1 - abar_t)): the x0 error alone weighs the low-noise steps by ~0, which
  leaves v untrained there and the sampler's last steps adding noise instead of removing it."""
  err = pred - x0
  if noise_std is not None:
    err = err / noise_std[:, None, None]
  d = {"diffusion": torch.mean(err ** 2),
       "velocity": torch.mean(((pred[:, 1:] - pred[:, :-1]) - (x0[:, 1:] - x0[:, :-1])) ** 2)}
  vp, vt = pred * std + mean, x0 * std + mean
  wp, wt = world_positions(vp), world_positions(vt)
  d["joints"] = torch.mean(torch.sum((wp - wt) ** 2, dim=-1))
  feet = wp[:, 1:, FOOT] - wp[:, :-1, FOOT]                          # (B, N-1, 4, 3)
  on = (vp[:, :-1, motion.CONTACT] > 0.5).float().detach()
  d["foot"] = torch.mean(torch.sum(feet ** 2, dim=-1) * on)
  return d


def build_parser() -> argparse.ArgumentParser:
  ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
  ap.add_argument("--run", default=str(td.REPO / "training" / "runs" / "sgmd"))
  ap.add_argument("--out", default=str(td.REPO / "models" / "sgmd.dncw"))
  ap.add_argument("--model-id", default="")
  ap.add_argument("--iters", type=int, default=6000)
  ap.add_argument("--batch", type=int, default=32)
  ap.add_argument("--lr", type=float, default=2e-4)
  ap.add_argument("--weight-decay", type=float, default=0.02)
  ap.add_argument("--warmup", type=int, default=200)
  ap.add_argument("--ema", type=float, default=0.999)
  ap.add_argument("--music-dropout", type=float, default=0.15)
  ap.add_argument("--style-dropout", type=float, default=0.15)
  ap.add_argument("--lambda-joints", type=float, default=1.0)
  ap.add_argument("--lambda-foot", type=float, default=10.0)
  ap.add_argument("--d-model", type=int, default=192)
  ap.add_argument("--layers", type=int, default=4)
  ap.add_argument("--music-layers", type=int, default=2)
  ap.add_argument("--heads", type=int, default=4)
  ap.add_argument("--frames", type=int, default=150)
  ap.add_argument("--dropout", type=float, default=0.1)
  ap.add_argument("--prediction", choices=("x0", "v"), default="x0",
                  help="the output's parameterisation (v: x0 = sqrt(abar) x_t - sqrt(1 - abar) out; tried, "
                       "not shipped: docs/diffusion.md section 3)")
  ap.add_argument("--no-mirror", action="store_true")
  ap.add_argument("--val-every", type=int, default=250)
  ap.add_argument("--ckpt-every", type=int, default=250)
  ap.add_argument("--seed", type=int, default=0)
  ap.add_argument("--weights-dtype", choices=("f16", "f32"), default="f16")
  ap.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
  return ap


def _val_set(data: WindowData, stats: Stats, n: int, steps: int, seed: int = 1234):
  rng = np.random.default_rng(seed)
  x0, music, style = data.batch(rng, n, stats)
  g = torch.Generator().manual_seed(seed)
  t = torch.linspace(0, steps - 1, n).round().long()
  noise = torch.randn(x0.shape, generator=g)
  return torch.from_numpy(x0), torch.from_numpy(music), torch.from_numpy(style), t, noise


def _one_hot(style: torch.Tensor, n_styles: int, drop: torch.Tensor | None = None) -> torch.Tensor:
  idx = style.clone()
  if drop is not None:
    idx[drop] = n_styles
  return torch.nn.functional.one_hot(idx, n_styles + 1).float()


def validate(model: SGMD, val, stats_t) -> dict:
  x0, music, style, t, noise = val
  abar = model.alphas_cumprod[t][:, None, None]
  xt = abar.sqrt() * x0 + (1 - abar).sqrt() * noise
  was_training = model.training
  with torch.no_grad():
    model.eval()
    pred = model(xt, t, music, _one_hot(style, model.cfg.n_styles), torch.ones(len(t), dtype=torch.bool))
    model.train(was_training)
    d = losses(pred, x0, *stats_t, noise_std=(1 - abar[:, 0, 0]).sqrt() if model.cfg.prediction == "v" else None)
  return {k: float(v) for k, v in d.items()}


def plot(history: dict, path: pathlib.Path) -> None:
  import matplotlib
  matplotlib.use("Agg")
  import matplotlib.pyplot as plt
  fig, axes = plt.subplots(1, 2, figsize=(11, 4))
  tr = history["train"]
  if tr:
    it = [r["iter"] for r in tr]
    for k in ("total", "diffusion", "velocity", "joints", "foot"):
      axes[0].plot(it, [r[k] for r in tr], label=k)
  axes[0].set_yscale("log")
  axes[0].set_title("training loss (mean over the last log interval)")
  axes[0].set_xlabel("iteration")
  axes[0].legend()
  va = history["val"]
  if va:
    it = [r["iter"] for r in va]
    for k in ("diffusion", "joints", "foot"):
      axes[1].plot(it, [r[k] for r in va], label=f"val {k}")
  axes[1].set_yscale("log")
  axes[1].set_title("validation (EMA weights, fixed noise and steps)")
  axes[1].set_xlabel("iteration")
  axes[1].legend()
  fig.tight_layout()
  fig.savefig(path, dpi=90)
  plt.close(fig)


def main(argv: list[str] | None = None) -> None:
  args = build_parser().parse_args(argv)
  if args.threads:
    torch.set_num_threads(args.threads)
  run = pathlib.Path(args.run)
  run.mkdir(parents=True, exist_ok=True)
  log = Logger(run / "train.log")
  split = td.load_split()
  styles = td.run_styles(split)
  cfg = SGMDConfig(d_model=args.d_model, n_layers=args.layers, n_music_layers=args.music_layers,
                   n_heads=args.heads, frames=args.frames, n_styles=len(styles), dropout=args.dropout,
                   prediction=args.prediction)
  t0 = time.time()
  train = WindowData.load(td.paired_ids(split["train"]), cfg.frames, cfg.frames_per_token, mirror=not args.no_mirror)
  val = WindowData.load(td.paired_ids(split["validation"]), cfg.frames, cfg.frames_per_token, mirror=False)
  log(f"sgmd data: {len(train.songs)} training dances, {len(val.songs)} validation ({time.time() - t0:.0f} s)")

  ckpt_path = run / "sgmd_ckpt.pt"
  torch.manual_seed(args.seed)
  model = SGMD(cfg)
  ema = copy.deepcopy(model).eval()
  opt = torch.optim.AdamW(model.parameters(), lr=args.lr, weight_decay=args.weight_decay)
  rng = np.random.default_rng(args.seed)
  history = {"train": [], "val": [], "args": vars(args)}
  start = 0
  if ckpt_path.is_file():
    ck = torch.load(ckpt_path, weights_only=False)
    if ck["config"] != vars(cfg):
      raise SystemExit(f"{ckpt_path} was trained with another configuration: use another --run")
    model.load_state_dict(ck["model"])
    ema.load_state_dict(ck["ema"])
    opt.load_state_dict(ck["opt"])
    rng.bit_generator.state = ck["rng"]
    torch.set_rng_state(ck["torch_rng"])
    stats = Stats(**{k: np.asarray(v) for k, v in ck["stats"].items()})
    history, start = ck["history"], ck["iter"]
    log(f"sgmd: resumed at iteration {start}")
  else:
    stats = train.stats(np.random.default_rng(args.seed + 1))
  stats_t = (torch.from_numpy(stats.pose_mean).float(), torch.from_numpy(stats.pose_std).float())
  val_set = _val_set(val, stats, 64, cfg.diffusion_steps)
  n_params = sum(p.numel() for p in model.parameters())
  log(f"sgmd: {n_params / 1e6:.2f} M parameters, {cfg.tokens} tokens per window, iterations {start}..{args.iters}")

  def lr_at(i: int) -> float:
    if i < args.warmup:
      return args.lr * (i + 1) / args.warmup
    f = (i - args.warmup) / max(1, args.iters - args.warmup)
    return args.lr * (0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * min(1.0, f))))

  acc, n_acc, t_log = {}, 0, time.time()
  for i in range(start, args.iters):
    for g in opt.param_groups:
      g["lr"] = lr_at(i)
    x0, music, style = (torch.from_numpy(a) for a in train.batch(rng, args.batch, stats))
    b = len(x0)
    t = torch.randint(0, cfg.diffusion_steps, (b,))
    noise = torch.randn_like(x0)
    abar = model.alphas_cumprod[t][:, None, None]
    xt = abar.sqrt() * x0 + (1 - abar).sqrt() * noise
    keep = torch.rand(b) >= args.music_dropout
    sw = _one_hot(style, cfg.n_styles, torch.rand(b) < args.style_dropout)
    pred = model(xt, t, music, sw, keep)
    d = losses(pred, x0, *stats_t, noise_std=(1 - abar[:, 0, 0]).sqrt() if cfg.prediction == "v" else None)
    total = d["diffusion"] + d["velocity"] + args.lambda_joints * d["joints"] + args.lambda_foot * d["foot"]
    opt.zero_grad(set_to_none=True)
    total.backward()
    torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
    opt.step()
    with torch.no_grad():
      for pe, pm in zip(ema.parameters(), model.parameters()):
        pe.mul_(args.ema).add_(pm.detach(), alpha=1 - args.ema)
    d["total"] = total
    for k, v in d.items():
      acc[k] = acc.get(k, 0.0) + float(v)
    n_acc += 1
    done = i + 1
    if done % 50 == 0 or done == args.iters:
      row = {"iter": done, **{k: v / n_acc for k, v in acc.items()}, "lr": lr_at(i),
             "s_per_iter": (time.time() - t_log) / n_acc}
      history["train"].append(row)
      log(f"sgmd iter {done}/{args.iters} " + " ".join(f"{k} {row[k]:.4f}" for k in
                                                     ("total", "diffusion", "velocity", "joints", "foot")) +
          f" ({row['s_per_iter']:.2f} s/iter)")
      acc, n_acc, t_log = {}, 0, time.time()
    if done % args.val_every == 0 or done == args.iters:
      v = validate(ema, val_set, stats_t)
      history["val"].append({"iter": done, **v})
      log(f"sgmd val {done}: " + json.dumps({k: round(x, 4) for k, x in v.items()}))
    if done % args.ckpt_every == 0 or done == args.iters:
      torch.save({"config": vars(cfg), "model": model.state_dict(), "ema": ema.state_dict(),
                  "opt": opt.state_dict(), "rng": rng.bit_generator.state, "torch_rng": torch.get_rng_state(),
                  "stats": {k: v.tolist() for k, v in vars(stats).items()}, "history": history, "iter": done},
                 str(ckpt_path) + ".tmp")
      pathlib.Path(str(ckpt_path) + ".tmp").replace(ckpt_path)
      (run / "history.json").write_text(json.dumps(history))
      plot(history, run / "training_sgmd.png")
  out = pathlib.Path(args.out)
  model_id = args.model_id or out.stem + "-" + time.strftime("%Y%m%d")
  export_sgmd(str(out), ema, stats, styles, {"model_id": model_id, "training": {
      "run": str(run), "iterations": args.iters, "seconds_per_iter": history["train"][-1]["s_per_iter"]
      if history["train"] else None, "final_val": history["val"][-1] if history["val"] else None,
      "args": vars(args)}}, weights_dtype=args.weights_dtype)
  log(f"sgmd export: {out} ({out.stat().st_size / 1e6:.1f} MB, model id {model_id})")


if __name__ == "__main__":
  main()
