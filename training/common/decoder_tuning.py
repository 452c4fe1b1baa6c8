"""Decoder-only fine-tuning of the pose VQ-VAEs, with an energy-matching term (the vqdec stage) and the
own-codes term (the owndec stage); the standalone command is training.experiments.vq_decoder.

    hist = finetune_decoder(vq, "upper", training_arrays("upper"), iters=1500, energy_weight=0.1, log=log)
    hist = finetune_decoder(vq, "upper", arrays, 1000, 0.1, own_dances=str(run / "own_dances"), own_weight=1,
                            own_anchor=100)

The encoders and codebooks stay frozen (eval mode: the EMA codebook is not updated), so every code, and the
sequence model trained on the codes, stays valid; only the causal decoders change. Loss per window:
vq_training.vq_loss (the shipped recipe's reconstruction, velocity and acceleration terms; the commitment term
is a constant here) plus `energy_weight` x `energy_loss`: per joint (the three position channels of a joint
together; the lower body's four root channels one by one), in metres, the window's mean squared velocity
and mean |acceleration| of the decoded motion against the real window's, as squared log-ratios. An L2-type
decoder outputs about the conditional mean of the motion given the codes and so loses energy
(docs/research-log.md, "Why FID_k stays ~20"); the energy term asks each window to keep its real energy.

With own_dances DIR and own_weight W (the owndec stage), the loss also has W x the own-codes term (OwnCodes):
DIR holds the engine's dances on the training songs (dance-generate JSON); windows of their codes are decoded
and, per style, the decoded motion's energy statistics are matched in mean and spread to the real training
dances of that style. The decoder was trained only on real code sequences; the sequence model's sequences
differ (their codes jump further between steps), and decoded from them each style's energy was off
(default-20261204-4 on the training songs, mean log kinetic energy per joint: waltz +0.57 real standard
deviations, rumba +0.27, tango -0.77). This term fits the decoder to the codes it will actually decode.
own_anchor A adds A x the squared change of each window's mean decoded pose against the decoder before
fine-tuning (posture kept; energy free).
"""
from __future__ import annotations

import copy
import json
import math
import pathlib
import time

import numpy as np
import torch
from tqdm import tqdm

from training.common.clips import style_index
from training.common.vq_training import sample_windows, training_clips, vq_loss
from training.model.vqvae import PoseVQVAE

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
                 energy_weight: float, groups, eps, own=None, own_weight: float = 0.0) -> dict:
  """One optimisation step on windows x (B, T, dim) (raw features). Returns the logged terms."""
  captured = {}
  hook = vq.decoder.register_forward_hook(lambda m, inp, out: captured.__setitem__("recon", out))
  try:
    loss, logs = vq_loss(vq, x, part)  # vq.eval(): the quantizer does not update its codebook
  finally:
    hook.remove()
  e = energy_loss(vq.denormalise(captured["recon"]), x, groups, eps)
  total = loss + energy_weight * e
  if own is not None:
    o, own_logs = own.loss()
    total = total + own_weight * o
    logs.update(own_logs)
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


def step_codes(frame_upper, frame_lower) -> tuple[np.ndarray, np.ndarray]:
  """A dance file's per-frame (upper, lower) codes -> the codes per model step. The engine decodes 4 frames
  per step in the model's tempo-normalised time and warps them to 30 fps, so a step covers about 4 / f real
  frames (f the song's tempo factor): runs of the same code pair are split into steps of the most common
  run length (the codes of one step always share a run; consecutive equal steps are recovered by length)."""
  u, l = np.asarray(frame_upper), np.asarray(frame_lower)
  change = np.flatnonzero((u[1:] != u[:-1]) | (l[1:] != l[:-1])) + 1
  starts = np.concatenate([[0], change])
  runs = np.diff(np.concatenate([starts, [len(u)]]))
  mode = np.bincount(runs).argmax()
  near = runs[np.abs(runs - mode) <= 1.5]
  length = near.mean()
  n = np.maximum(1, np.rint(runs / length)).astype(int)
  return np.repeat(u[starts], n), np.repeat(l[starts], n)


class OwnCodes:
  """The moment-matching term on the sequence model's own codes: windows of `steps` model steps of the
  engine's dances on the training songs (step_codes), decoded by the part's decoder; per style, the mean
  and standard deviation over windows of each channel group's log energy statistics (window_energy) against
  the same statistics of the real training dances of that style, in units of the real standard deviation.
  The decoder does not see the style; the term asks that, decoded from the codes the model actually samples
  (which jump further between steps than the real dances' encodings), each style's motion has its real
  energy, on average and in spread. An approximation: the codes are in the model's tempo-normalised time
  and the real dances in their own, so a song far from its style's reference tempo is matched to motion a
  little faster or slower than its own (energy scales with the tempo factor squared; the training songs'
  factors spread around 1)."""

  def __init__(self, vq: PoseVQVAE, dances: list[tuple[int, np.ndarray]],
               real: dict[int, list[np.ndarray]], groups, eps, steps: int = 32, per_style: int = 8,
               seed: int = 0, real_windows: int = 512, anchor: float = 0.0):
    self.vq, self.groups, self.eps, self.steps, self.per_style = vq, groups, eps, steps, per_style
    self.anchor = anchor
    # The decoder as it was: the posture anchor keeps each window's mean pose where it decoded before.
    self.before = copy.deepcopy(vq.decoder).eval() if anchor > 0 else None
    if self.before is not None:
      for p in self.before.parameters():
        p.requires_grad_(False)
    self.rng = np.random.default_rng(seed)
    frames = steps * 4  # downsampling 4 (VQConfig)
    # Styles with at least one code sequence of `steps` steps and one real clip of as many frames.
    self.styles = sorted(s for s in {t for t, _ in dances} & set(real)
                         if any(len(c) >= steps for t, c in dances if t == s)
                         and any(len(a) >= frames for a in real[s]))
    if not self.styles:
      raise ValueError(f"OwnCodes: no style has both a dance of {steps} steps and a real clip of {frames} frames")
    self.codes = {s: [c for t, c in dances if t == s and len(c) >= steps] for s in self.styles}
    self.target = {}
    for s in self.styles:
      arrs = [a for a in real[s] if len(a) >= frames]
      lengths = np.array([len(a) - frames + 1 for a in arrs], dtype=np.float64)
      wins = []
      for i in self.rng.choice(len(arrs), real_windows, p=lengths / lengths.sum()):
        o = self.rng.integers(0, len(arrs[i]) - frames + 1)
        wins.append(arrs[i][o:o + frames])
      with torch.no_grad():
        e = self.log_energy(torch.from_numpy(np.stack(wins)))
      self.target[s] = (e.mean(0), e.std(0) + 1e-3)

  def log_energy(self, x: torch.Tensor) -> torch.Tensor:
    return torch.log(window_energy(x[:, ENERGY_SKIP:], self.groups) + self.eps)

  def sample(self, s: int) -> torch.Tensor:
    seqs = self.codes[s]
    out = []
    for i in self.rng.integers(0, len(seqs), self.per_style):
      o = self.rng.integers(0, len(seqs[i]) - self.steps + 1)
      out.append(seqs[i][o:o + self.steps])
    return torch.from_numpy(np.stack(out)).long()

  def loss(self) -> tuple[torch.Tensor, dict]:
    terms, logs = [], {}
    anchors = []
    for s in self.styles:
      z = self.vq.quantizer.codebook[self.sample(s)]
      out = self.vq.decoder(z)
      dec = self.vq.denormalise(out)
      e = self.log_energy(dec)
      mu, sd = self.target[s]
      dm = (e.mean(0) - mu) / sd
      ds = (e.std(0) - sd) / sd
      terms.append(dm.pow(2).mean() + ds.pow(2).mean())
      if self.before is not None:
        with torch.no_grad():
          ref = self.before(z)
        anchors.append((out[:, ENERGY_SKIP:].mean(1) - ref[:, ENERGY_SKIP:].mean(1)).pow(2).mean())
      logs[f"own_mean_{s}"] = float(dm[:, 0].mean())
    total = torch.stack(terms).mean()
    logs["own"] = float(total)
    if anchors:
      a = torch.stack(anchors).mean()
      logs["anchor"] = float(a)
      total = total + self.anchor * a
    return total, logs


def load_own_codes(directory: str, part: str) -> list[tuple[int, np.ndarray]]:
  """Every dance file in `directory` (dance-generate JSON, one style each) -> (style index, step codes)."""
  out = []
  for p in sorted(pathlib.Path(directory).glob("*.json")):
    d = json.loads(p.read_text())
    if not d.get("style") or not d.get("upper_codes") or not d.get("lower_codes"):
      raise ValueError(f"{p}: not a dance-generate file with a style and per-frame codes")
    style = max(d["style"].items(), key=lambda kv: kv[1])[0]
    try:
      row = style_index(style)
    except ValueError as e:
      raise ValueError(f"{p}: {e}") from None
    up, low = step_codes(d["upper_codes"], d["lower_codes"])
    out.append((row, up if part == "upper" else low))
  if not out:
    raise ValueError(f"no dance files (*.json) in {directory}")
  return out


def real_by_style(part: str) -> dict[int, list[np.ndarray]]:
  """The training clips of `part` grouped by style index."""
  out: dict[int, list[np.ndarray]] = {}
  for c in training_clips(False):
    out.setdefault(c.style, []).append(getattr(c, part))
  return out


def finetune_decoder(vq: PoseVQVAE, part: str, arrays: list[np.ndarray], iters: int, energy_weight: float,
                     lr: float = 1e-4, batch: int = 32, seed: int = 0, log=print,
                     log_every: int = 100, own_dances: str | None = None,
                     own_weight: float = 0.0, own_anchor: float = 0.0, own_steps: int = 32) -> list[dict]:
  """Fine-tunes vq.decoder in place (cosine decay to 0.1 lr, as train_vq); returns the loss history.
  With `own_dances` (a directory of the engine's dances on the training songs) and `own_weight` > 0, adds
  own_weight x OwnCodes.loss."""
  torch.manual_seed(seed)
  rng = np.random.default_rng(seed)
  params = freeze_all_but_decoder(vq)
  groups = channel_groups(vq.cfg.in_dim)
  eps = energy_eps(arrays, groups, np.random.default_rng(seed + 1))
  own = None
  if own_dances and own_weight > 0:
    own = OwnCodes(vq, load_own_codes(own_dances, part), real_by_style(part), groups, eps, seed=seed + 2,
                  anchor=own_anchor, steps=own_steps)
  opt = torch.optim.AdamW(params, lr=lr, weight_decay=0.0)
  history, t0, acc = [], time.time(), {}
  for it in tqdm(range(iters), desc=f"vqdec-{part}", mininterval=10):
    for g in opt.param_groups:
      g["lr"] = lr * (0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * it / iters)))
    logs = decoder_step(vq, opt, params, sample_windows(arrays, batch, rng), part, energy_weight, groups, eps,
                        own, own_weight)
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
  """The VQ stage's training motion of `part` (vq_training.training_clips: split.json's "train", optionally
  mirrored; the shipped model: not mirrored)."""
  return [getattr(c, part) for c in training_clips(mirror)]
