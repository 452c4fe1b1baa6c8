"""Pose VQ-VAE training (upper and lower body) and its validation report: what the vq stage runs, and the
reconstruction figures the vqdec and owndec stages report too.

    vq, history = train_vq("upper", [clip.upper for clip in training_clips()], cfg, iters, run / "vq_upper.pt", log)
    report = validation_report({"upper": vq_u, "lower": vq_l}, validation_clips)

Losses (Bailando's recipe): smooth-L1 reconstruction of the normalised features, their velocity and
acceleration (weighted by `VQConfig.vel_weight` / `acc_weight`; training.train's defaults are 4 since
2026-12-03: at weight 1 those terms were an order of magnitude below the position term and the decoder kept
only 74-79 % of the real acceleration RMS, docs/research-log.md), commitment. For the lower body an optional
term (`VQConfig.path_weight`, default 0) adds the integrated root path and heading error over the whole window
(metres, radians). It was on (weight 1) until 2026-12-02 and was measured to cost most of the lower body's pose
accuracy for little less drift (docs/research-log.md, "The previous model (`default-20261202-2`)"), so it is off.
"""
from __future__ import annotations

import math
import time

import numpy as np
import torch
import torch.nn.functional as F
from tqdm import tqdm

from training.common import clips as td
from training.data import representation as rep
from training.model.config import VQConfig
from training.model.vqvae import PoseVQVAE

WINDOW = 64  # frames


def integrate_root_torch(lower: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
  """lower (B, T, 31) denormalised -> heading (B, T), root path (B, T, 2) (x, z), from 0 at the window start."""
  theta = torch.cumsum(lower[..., rep.ROOT_YAW_RATE], dim=1)
  vx, vz = lower[..., rep.ROOT_VX], lower[..., rep.ROOT_VZ]
  c, s = torch.cos(theta), torch.sin(theta)
  step = torch.stack([c * vx + s * vz, -s * vx + c * vz], dim=-1)  # R_y(theta) (vx, 0, vz)
  return theta, torch.cumsum(step, dim=1)


def vq_loss(vq: PoseVQVAE, x: torch.Tensor, part: str) -> tuple[torch.Tensor, dict]:
  xn = vq.normalise(x)
  recon, _, commit = vq(xn)
  rec = F.smooth_l1_loss(recon, xn)
  vel = F.smooth_l1_loss(recon[:, 1:] - recon[:, :-1], xn[:, 1:] - xn[:, :-1])
  acc = F.smooth_l1_loss(recon[:, 2:] - 2 * recon[:, 1:-1] + recon[:, :-2],
                         xn[:, 2:] - 2 * xn[:, 1:-1] + xn[:, :-2])
  loss = rec + vq.cfg.vel_weight * vel + vq.cfg.acc_weight * acc + vq.cfg.commit_weight * commit
  logs = {"rec": float(rec), "vel": float(vel), "acc": float(acc), "commit": float(commit)}
  if part == "lower":
    th_r, p_r = integrate_root_torch(vq.denormalise(recon))
    th_x, p_x = integrate_root_torch(x)
    path = (p_r - p_x).norm(dim=-1).mean() * 10.0 + (th_r - th_x).abs().mean()
    loss = loss + vq.cfg.path_weight * path
    logs["path"] = float(path)
  return loss, logs


def training_clips(mirror: bool = False) -> list:
  """The VQ-VAEs' training motion: every clip of split.json's "train" (Tang, CMU salsa, Perfume), motion only;
  with `mirror` also each one reflected left-right (skeleton.mirror_positions)."""
  ids = td.load_split()["train"]
  clips = [td.load_clip(i, with_music=False) for i in ids]
  if mirror:
    clips += [td.load_clip(i, with_music=False, mirror=True) for i in ids]
  return clips


def sample_windows(arrays: list[np.ndarray], batch: int, rng: np.random.Generator) -> torch.Tensor:
  lengths = np.array([len(a) for a in arrays], dtype=np.float64)
  probs = np.maximum(lengths - WINDOW, 1) / np.maximum(lengths - WINDOW, 1).sum()
  out = []
  for i in rng.choice(len(arrays), batch, p=probs):
    a = arrays[i]
    s = rng.integers(0, len(a) - WINDOW + 1)
    out.append(a[s:s + WINDOW])
  return torch.from_numpy(np.stack(out))


def train_vq(part: str, train_arrays: list[np.ndarray], cfg: VQConfig, iters: int, ckpt_path, log,
             batch: int = 32, lr: float = 3e-4, seed: int = 0, save_every: int = 500,
             stop_after: int | None = None) -> tuple[PoseVQVAE, list[dict]]:
  """Trains one VQ-VAE, resuming from `ckpt_path` if it exists; returns the model and the loss history.

  The checkpoint holds the window sampler's and torch's random states, so a resumed run continues exactly
  as the uninterrupted one would have (before, a resume restarted the sampler from its seed and trained on
  the first windows again). `stop_after` ends (and saves) after that many iterations of the schedule."""
  torch.manual_seed(seed)
  rng = np.random.default_rng(seed)
  vq = PoseVQVAE(cfg)
  allx = np.concatenate(train_arrays)
  with torch.no_grad():
    vq.pose_mean.copy_(torch.from_numpy(allx.mean(0)))
    vq.pose_std.copy_(torch.from_numpy(np.maximum(allx.std(0), 1e-3)))
  opt = torch.optim.AdamW(vq.parameters(), lr=lr, weight_decay=0.0)
  history, start = [], 0
  if ckpt_path.is_file():
    ck = torch.load(ckpt_path)
    vq.load_state_dict(ck["model"])
    opt.load_state_dict(ck["opt"])
    history, start = ck["history"], ck["iter"]
    if "rng" in ck:
      rng.bit_generator.state = ck["rng"]
      torch.set_rng_state(ck["torch_rng"])
  vq.train()
  end = iters if stop_after is None else min(iters, stop_after)
  t0 = time.time()
  for it in tqdm(range(start, end), desc=f"vq-{part}", initial=start, total=iters, mininterval=10):
    for g in opt.param_groups:  # cosine decay
      g["lr"] = lr * (0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * it / iters)))
    x = sample_windows(train_arrays, batch, rng)
    loss, logs = vq_loss(vq, x, part)
    opt.zero_grad()
    loss.backward()
    torch.nn.utils.clip_grad_norm_(vq.parameters(), 1.0)
    opt.step()
    if it % 50 == 0 or it == iters - 1:
      logs.update(iter=it, loss=float(loss))
      history.append(logs)
    if it % save_every == save_every - 1 or it == end - 1:
      torch.save({"model": vq.state_dict(), "opt": opt.state_dict(), "history": history, "iter": it + 1,
                  "cfg": cfg.to_dict(), "rng": rng.bit_generator.state, "torch_rng": torch.get_rng_state()},
                 ckpt_path)
      log(f"vq-{part} iter {it + 1}/{iters} loss {float(loss):.4f} {logs} ({time.time() - t0:.0f} s)")
  vq.eval()
  return vq, history


@torch.no_grad()
def reconstruct(vq: PoseVQVAE, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
  """Whole-sequence encode + causal decode; x (T, dim) -> (recon (T', dim), codes (T'/4,)), T' = T - T % 4."""
  t = len(x) - len(x) % 4
  xn = vq.normalise(torch.from_numpy(x[:t]))[None]
  codes = vq.encode(xn)
  return vq.denormalise(vq.decode_codes(codes))[0].numpy(), codes[0].numpy()


def validation_report(vqs: dict[str, PoseVQVAE], clips) -> dict:
  """Reconstruction on validation clips: mm/joint in the body (facing) frame, i.e. the pose the features
  describe; mm/joint of global positions after integrating the root from the first real frame; codebook
  usage; heading (deg) and path (m) drift after 60 s of integration."""
  body, glob, used, drifts = [], [], {"upper": set(), "lower": set()}, []
  for c in clips:
    ru, cu = reconstruct(vqs["upper"], c.upper)
    rl, cl = reconstruct(vqs["lower"], c.lower)
    used["upper"].update(cu.tolist())
    used["lower"].update(cl.tolist())
    t = len(ru)
    du = np.linalg.norm((ru - c.upper[:t]).reshape(t, 15, 3), axis=-1)
    dl = np.linalg.norm((rl[:, :27] - c.lower[:t, :27]).reshape(t, 9, 3), axis=-1)
    body.append(np.concatenate([du, dl], axis=1).mean())
    real = c.positions[:t].astype(np.float64)
    theta0 = float(rep.facing_yaw(real[:1])[0])
    pos = rep.decode(ru, rl, theta_init=theta0, root_init=(real[0, 0, 0], real[0, 0, 2]))
    glob.append(np.linalg.norm(pos - real, axis=-1).mean())
    n = min(t, 60 * 30)
    drifts.append(rep.heading_and_path_drift(real[:n], pos[:n]))
  k = vqs["upper"].cfg.codebook_size
  return {"mm_per_joint_body_frame": 1000 * float(np.mean(body)),
          "mm_per_joint_global": 1000 * float(np.mean(glob)),
          "codebook_usage_upper": len(used["upper"]) / k, "codebook_usage_lower": len(used["lower"]) / k,
          "heading_drift_deg_60s": float(np.mean([d["heading_deg_end"] for d in drifts])),
          "path_drift_m_60s": float(np.mean([d["path_m_end"] for d in drifts])),
          "clip_seconds": [round(len(c.upper) / 30.0, 1) for c in clips]}
