"""The sequence model's training data: tokens of the training clips (codes of every step and the music beside
them) and the random windows a training batch is made of, with past-motion dropout.

    toks = build_tokens(ids, (1.0,), vqs, log, cache=run / "tokens_val_1.pt")
    inputs, targets = make_batch(toks, cfg, rng, code_mask=0.4, style_dropout=STYLE_DROPOUT)
    # inputs: music (B, STEPS, 4 * F), pre (B, STEPS, P), upper and lower input codes (B, STEPS) (K = BOS),
    #         style weights (B, n_styles + 1); targets: the next codes (B, STEPS) per part

Making the music matter (docs/research-log.md): tempo-augmented pairs (clips.TEMPO_FACTORS), the rhythm
clock (beat/bar phase and tempo features + PRE) and past-motion dropout: each input code is replaced by BOS
with probability code_mask and by a random code with probability code_mask / 4 (mask_codes), so that the
past motion alone cannot carry the timing and the model has to read the clock from the music.
"""
from __future__ import annotations

import collections
import math
import pathlib

import numpy as np
import torch
from tqdm import tqdm

from training.common import clips as td
from training.model.config import SeqConfig

STEPS = 64          # training window, code steps (8.5 s)
BATCH = 16
STYLE_DROPOUT = 0.15


def mask_codes(codes: np.ndarray, k: int, code_mask: float, rng: np.random.Generator) -> None:
  """Past-motion dropout, in place: each code becomes BOS (k) with probability code_mask and a random code
  with probability code_mask / 4 (make_batch's rule)."""
  r = rng.random(len(codes))
  codes[r < code_mask] = k
  rnd = (r >= code_mask) & (r < code_mask * 1.25)
  codes[rnd] = rng.integers(0, k, int(rnd.sum()))


def tokenize(clip: td.Clip, vqs) -> dict:
  """Codes of every period and the per-step music of one clip; music arrays cover 4 * n_periods frames."""
  n = len(clip.upper) // 4
  out = {"id": clip.motion_id, "factor": clip.factor, "style": clip.style}
  for part in ("upper", "lower"):
    vq = vqs[part]
    x = torch.from_numpy(getattr(clip, part)[:4 * n])
    out[part] = vq.encode(vq.normalise(x)[None])[0].numpy().astype(np.int64)
  out["music"] = clip.features[:4 * n].reshape(n, -1)
  out["pre"] = clip.pre[:4 * n][3::4]
  return out


def build_tokens(ids, factors, vqs, log, cache: pathlib.Path | None = None,
                 style_refs: dict[str, float] | None = None, bar_clock: dict | None = None,
                 mirror: bool = False, warp_factors: tuple[float, ...] = (1.0,),
                 fold_tempo: bool = False) -> list[dict]:
  """Tokens of every (clip, factor); cached in `cache` (a file next to the VQ-VAE checkpoints) if given.
  style_refs: clips on the engine's tempo-normalised timeline (clips.load_warped_clip) at their
  style's reference tempo, one per song and factor of `warp_factors` (`factors` are not used: the clock
  removes the tempo from the motion; the warp factors stretch the music only, whose features still carry
  the tempo).
  bar_clock (with style_refs): the bar phase features are the bar clock's (clips.BAR_CLOCK).
  mirror: every clip also reflected left-right (skeleton.mirror_positions) on the same music: twice the
  dances, the turns and the arm styling in both directions.
  fold_tempo (with style_refs): the tempo features folded to the reference (clips.load_warped_clip)."""
  if style_refs:
    factors = tuple(warp_factors)
  if cache is not None and cache.is_file():
    toks = torch.load(cache)
    if (sorted({t["id"] for t in toks}) == sorted(ids) and sorted({t["factor"] for t in toks}) == sorted(factors)
        and {t.get("mirror", False) for t in toks} == ({False, True} if mirror else {False})):
      return toks
  toks = []
  for i in tqdm(ids, desc="tokens", mininterval=10):
    for f in factors:
      for m in ((False, True) if mirror else (False,)):
        if style_refs:
          style = str(np.load(td.MOTION_CACHE / f"{i}.npz")["style"])
          clip = td.load_warped_clip(i, style_refs[style], bar_beats=td.bar_beats_of(style, bar_clock), mirror=m,
                                     factor=f, fold_tempo=fold_tempo)
        else:
          clip = td.load_clip(i, f, mirror=m)
        toks.append(dict(tokenize(clip, vqs), mirror=m))
  log(f"tokens: {len(toks)} clips, {sum(len(t['upper']) for t in toks)} steps")
  if cache is not None:
    torch.save(toks, cache)
  return toks


def window_probs(toks, ok, steps: int, style_balance: float = 1.0, self_share: float | None = None) -> np.ndarray:
  """How often each usable clip (indices `ok`) is drawn: in proportion to its number of window starts, with
  each style's total share then set in proportion to (its windows) ** style_balance. 1 keeps the data's
  shares (waltz ~58 % of the Tang training steps, tango ~4 %); 0 gives every style the same share; 0.5 is
  in between. Within a style the clips keep their relative weights. A song's versions (tempo factors,
  mirror images) share its weight: augmenting some songs more than others does not change their shares.
  self_share: the model's own kept draws (clips marked "own_draw", training.experiments.self_rollouts) then get this
  share of the windows and the real clips the rest (None: by their lengths like any clip)."""
  lens = np.array([len(toks[j]["upper"]) for j in ok], np.float64) - steps
  versions = collections.Counter(toks[j].get("id") for j in ok)
  if len(set(versions.values())) > 1:  # (equal counts: the same shares, left bit-exact)
    lens /= np.array([versions[toks[j].get("id")] for j in ok], np.float64)
  probs = lens / lens.sum()
  if style_balance != 1.0:
    styles = np.array([toks[j]["style"] for j in ok])
    for st in np.unique(styles):
      share = probs[styles == st].sum()
      probs[styles == st] *= share ** style_balance / share
    probs /= probs.sum()
  if self_share is not None:
    own = np.array([bool(toks[j].get("own_draw", False)) for j in ok])
    if own.any() and (~own).any():
      probs[own] *= self_share / probs[own].sum()
      probs[~own] *= (1.0 - self_share) / probs[~own].sum()
  return probs


def make_batch(toks, cfg: SeqConfig, rng, batch=BATCH, steps=STEPS, code_mask=0.0, style_dropout=0.0,
               music_from=None, style_balance: float = 1.0, self_share: float | None = None):
  """Random windows. Inputs: codes of periods t0..t0+L-1 (BOS at the song start), music of t+s.
  music_from: optional list of clips to take the music from instead (music-ablation); style_balance:
  window_probs; self_share: window_probs."""
  s, k = cfg.music_lookahead_steps, cfg.codebook_size
  lens = np.array([len(t["upper"]) for t in toks])
  ok = np.flatnonzero(lens > steps + s + 1)
  probs = window_probs(toks, ok, steps, style_balance, self_share)
  mus, pres, us, ls, tu, tl, sw = [], [], [], [], [], [], []
  for j in rng.choice(ok, batch, p=probs):
    t = toks[j]
    t0 = 0 if rng.random() < 0.1 else int(rng.integers(0, len(t["upper"]) - steps - s))
    src = t if music_from is None else music_from[j]
    m = src["music"][t0 + s:t0 + s + steps]
    p = src["pre"][t0 + s:t0 + s + steps]
    if len(m) < steps:  # another song shorter than this window: wrap it
      reps = math.ceil(steps / max(len(m), 1)) + 1
      m = np.concatenate([src["music"]] * reps)[:steps]
      p = np.concatenate([src["pre"]] * reps)[:steps]
    u = t["upper"][t0:t0 + steps].copy()
    l = t["lower"][t0:t0 + steps].copy()
    if t0 == 0:
      u[0] = l[0] = k
    for c in (u, l):
      mask_codes(c, k, code_mask, rng)
    mus.append(m)
    pres.append(p)
    us.append(u)
    ls.append(l)
    tu.append(t["upper"][t0 + 1:t0 + steps + 1])
    tl.append(t["lower"][t0 + 1:t0 + steps + 1])
    w = np.zeros(cfg.n_styles + 1, np.float32)
    w[cfg.n_styles if rng.random() < style_dropout else t["style"]] = 1
    sw.append(w)
  f = lambda a, dt=torch.float32: torch.from_numpy(np.stack(a)).to(dt)  # noqa: E731
  return (f(mus), f(pres), f(us, torch.long), f(ls, torch.long), f(sw)), (f(tu, torch.long), f(tl, torch.long))
