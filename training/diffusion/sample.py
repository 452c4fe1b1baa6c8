"""SGMD's sampler in PyTorch: the reference the engine's (engine/diffusion/) is checked against, and a
quick way to look at a trained model (docs/diffusion.md sections 4-5).

    model, stats, meta = load_sgmd("models/sgmd.dncw")
    x0 = ddim_window(model, c, c_null, style_w, noise, steps=50, guidance=1.0, known=k, mask=m)
    pos = dance(model, stats, features, pre, style="waltz", seed=0)          # (T, 24, 3), whole song
    python -m training.diffusion.sample --model models/sgmd.dncw --audio SONG.wav --style waltz --out d.json
"""
from __future__ import annotations

import argparse
import json

import numpy as np
import torch

from training.diffusion import motion
from training.diffusion.data import Stats, music_tokens
from training.diffusion.export import load_sgmd
from training.features.extract import extract_features
from training.fixtures import skeleton_meta
from training.model.sgmd import SGMD


def ddim_timesteps(total: int, steps: int) -> list[int]:
  """tau_i = round((S - 1 - i) (T - 1) / (S - 1)), i = 0..S-1 (T - 1 first, 0 last); S = 1: [T - 1]."""
  if steps <= 1:
    return [total - 1]
  return [int(round((steps - 1 - i) * (total - 1) / (steps - 1))) for i in range(steps)]


@torch.no_grad()
def ddim_window(model: SGMD, c: torch.Tensor, c_null: torch.Tensor | None, style_w: torch.Tensor,
                noise: torch.Tensor, steps: int, guidance: float = 1.0, known: torch.Tensor | None = None,
                mask: torch.Tensor | None = None) -> torch.Tensor:
  """One window, deterministic DDIM (eta 0) from x_T = noise (N, D), with the known values imposed each step
  (x_t' = M (sqrt(abar_t') k + sqrt(1 - abar_t') noise) + (1 - M) x_t'). c, c_null: encoded music (1, n, d)."""
  abar = model.alphas_cumprod.double()
  taus = ddim_timesteps(model.cfg.diffusion_steps, steps)
  x = noise[None].float()
  m = mask[None].float() if mask is not None else None
  k = known[None].float() if known is not None else None

  def impose(x: torch.Tensor, t: int | None) -> torch.Tensor:
    if m is None:
      return x
    if t is None:
      return m * k + (1 - m) * x
    a = float(abar[t])
    return m * (a ** 0.5 * k + (1 - a) ** 0.5 * noise[None]) + (1 - m) * x

  x = impose(x, taus[0])
  for i, t in enumerate(taus):
    tt = torch.tensor([t])
    x0 = model.denoise(x, tt, c, style_w)
    if guidance != 1.0:
      x0 = guidance * x0 + (1 - guidance) * model.denoise(x, tt, c_null, style_w)
    if i == len(taus) - 1:
      x = impose(x0, None)
      break
    a, a2 = float(abar[t]), float(abar[taus[i + 1]])
    eps = (x - a ** 0.5 * x0) / (1 - a) ** 0.5
    x = impose(a2 ** 0.5 * x0 + (1 - a2) ** 0.5 * eps, taus[i + 1])
  return x[0]


def style_weights(meta: dict, style: str | None) -> torch.Tensor:
  n = len(meta["styles"])
  w = torch.zeros(1, n + 1)
  w[0, meta["styles"].index(style) if style not in (None, "", "none") else n] = 1.0
  return w


@torch.no_grad()
def dance(model: SGMD, stats: Stats, features: np.ndarray, pre: np.ndarray, style: str | None, meta: dict,
          seed: int = 0, steps: int = 50, guidance: float = 1.0, overlap: int | None = None) -> np.ndarray:
  """A whole song: windows of N frames, each after the first starting N - overlap frames after the one before
  and knowing the frames they share (docs/diffusion.md section 5). Returns world positions (T, 24, 3)."""
  cfg = model.cfg
  n, k = cfg.frames, cfg.frames_per_token
  overlap = n // 2 if overlap is None else overlap
  total = len(features)
  starts = [0]
  while starts[-1] + n < total:
    starts.append(min(starts[-1] + n - overlap, total - n))
  out = np.zeros((max(total, n), 24, 3))
  done = 0
  g = torch.Generator().manual_seed(seed)
  sw = style_weights(meta, style)
  c_null = model.music_null[None]
  for s in starts:
    f, p = features[s:s + n], pre[s:s + n]
    if len(f) < n:  # a song shorter than a window: its last frame repeated
      f = np.concatenate([f, np.repeat(f[-1:], n - len(f), 0)])
      p = np.concatenate([p, np.repeat(p[-1:], n - len(p), 0)])
    mt = torch.from_numpy(music_tokens(f, p, stats, k)).float()[None]
    c = model.encode_music(mt, torch.ones(1, dtype=torch.bool))
    known = mask = None
    yaw, origin = 0.0, np.zeros(2)
    shared = done - s
    if shared > 0:
      yaw, origin = motion.frame_of(out[s])
      v = motion.motion_vector(motion.positions_in_frame(out[s:done], yaw, origin))
      known = torch.zeros(n, motion.POSE_DIM)
      mask = torch.zeros(n, motion.POSE_DIM)
      known[:shared] = torch.from_numpy((v - stats.pose_mean) / stats.pose_std).float()
      mask[:shared] = 1.0
    noise = torch.randn(n, motion.POSE_DIM, generator=g)
    x = ddim_window(model, c, c_null, sw, noise, steps, guidance, known, mask).numpy()
    pos = motion.positions_of(x * stats.pose_std + stats.pose_mean)
    world = motion.positions_from_frame(pos, yaw, origin)
    out[max(s, done):s + n] = world[max(0, shared):]
    done = s + n
  return out[:total]


def main(argv: list[str] | None = None) -> None:
  ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
  ap.add_argument("--model", default="models/sgmd.dncw")
  ap.add_argument("--audio", required=True)
  ap.add_argument("--style", default="")
  ap.add_argument("--seed", type=int, default=0)
  ap.add_argument("--steps", type=int, default=50)
  ap.add_argument("--guidance", type=float, default=1.0)
  ap.add_argument("--seconds", type=float, default=0.0, help="only the first S seconds (0: all)")
  ap.add_argument("--out", required=True)
  args = ap.parse_args(argv)
  model, stats, meta = load_sgmd(args.model)
  m = extract_features(args.audio)
  f, p = m["features"], m["pre"]
  if args.seconds > 0:
    f, p = f[:int(args.seconds * 30)], p[:int(args.seconds * 30)]
  pos = dance(model, stats, f, p, args.style, meta, seed=args.seed, steps=args.steps, guidance=args.guidance)
  sk = skeleton_meta()
  with open(args.out, "w") as fh:
    json.dump({"format": "dance-motion/v1", "fps": 30, "units": "m", "up_axis": "y", "joint_names": sk["joint_names"],
               "parents": sk["parents"], "positions": np.round(pos, 5).tolist(), "audio_offset_s": 0.0,
               "source": f"training.diffusion.sample {meta.get('model_id')}"}, fh)


if __name__ == "__main__":
  main()
