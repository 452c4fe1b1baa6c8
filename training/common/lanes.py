"""Training the sequence model with its state carried across a song (truncated backpropagation through time).

The engine runs a song from its first step to its last with the Mamba states and the KV caches carried
(docs/model.md section 5); windows drawn at random start mid-song from a zero state instead, so the model
never learns what its state looks like a minute into a song. `Lanes` keeps `batch` lanes, each walking
through one song window by window from the song's start (BOS): every training step takes each lane's next
window, and the model starts it from the state the lane's previous window left (detached: gradients stay
inside a window). When a lane's song has no whole window left, the lane starts another song, drawn so that
each song's share of the windows is window_probs' (its style's share set by --style-balance), with a zero
state; rows that start a song while others continue are reset by `reset_rows`.

    lanes = Lanes(toks, cfg, rng, batch=16, steps=64, style_balance=0.5)
    inputs, targets, fresh = lanes.next(code_mask=0.4, style_dropout=0.15)
    state = reset_rows(detach(state), fresh)
    lu, ll, state = model.forward_with_state(*inputs, state)
"""
from __future__ import annotations

import numpy as np
import torch

from training.common.tokens import mask_codes, window_probs
from training.model.config import SeqConfig


class Lanes:
  """`batch` lanes walking through songs window by window (module docstring). The position of every lane
  is in `snapshot()` / `restore()`, so a resumed run continues the same walk."""

  def __init__(self, toks: list[dict], cfg: SeqConfig, rng: np.random.Generator, batch: int, steps: int,
               style_balance: float = 1.0):
    self.toks, self.cfg, self.rng, self.batch, self.steps = toks, cfg, rng, batch, steps
    s = cfg.music_lookahead_steps
    lens = np.array([len(t["upper"]) for t in toks])
    self.ok = np.flatnonzero(lens > steps + s + 1)
    if len(self.ok) == 0:
      raise ValueError(f"Lanes: no song is longer than one window ({steps + s + 1} steps)")
    # window_probs gives each clip's share of the windows; a lane stays on a clip for about
    # len / steps windows, so the clip is drawn in proportion to share / windows.
    share = window_probs(toks, self.ok, steps, style_balance)
    visit = share / np.maximum((lens[self.ok] - s - 1) // steps, 1)
    self.visit_probs = visit / visit.sum()
    self.clip = [-1] * batch
    self.pos = [0] * batch
    self.style = [0] * batch

  def _start(self, lane: int, style_dropout: float) -> None:
    j = int(self.rng.choice(self.ok, p=self.visit_probs))
    self.clip[lane], self.pos[lane] = j, 0
    dropped = self.rng.random() < style_dropout  # style "none" for the whole visit
    self.style[lane] = self.cfg.n_styles if dropped else int(self.toks[j]["style"])

  def next(self, code_mask: float = 0.0, style_dropout: float = 0.0):
    """Each lane's next window: ((music, pre, u, l, style_w), (target_u, target_l)) as make_batch, and
    `fresh` (B,) bool: the lanes that started a song here (their carried state must be reset)."""
    s, k, steps = self.cfg.music_lookahead_steps, self.cfg.codebook_size, self.steps
    fresh = np.zeros(self.batch, bool)
    mus, pres, us, ls, tu, tl, sw = [], [], [], [], [], [], []
    for lane in range(self.batch):
      j = self.clip[lane]
      if j < 0 or self.pos[lane] + steps + s + 1 > len(self.toks[j]["upper"]):
        self._start(lane, style_dropout)
        fresh[lane] = True
        j = self.clip[lane]
      t, t0 = self.toks[j], self.pos[lane]
      mus.append(t["music"][t0 + s:t0 + s + steps])
      pres.append(t["pre"][t0 + s:t0 + s + steps])
      u = np.array(t["upper"][t0:t0 + steps])
      l = np.array(t["lower"][t0:t0 + steps])
      if t0 == 0:
        u[0] = l[0] = k
      mask_codes(u, k, code_mask, self.rng)
      mask_codes(l, k, code_mask, self.rng)
      us.append(u)
      ls.append(l)
      tu.append(t["upper"][t0 + 1:t0 + steps + 1])
      tl.append(t["lower"][t0 + 1:t0 + steps + 1])
      w = np.zeros(self.cfg.n_styles + 1, np.float32)
      w[self.style[lane]] = 1
      sw.append(w)
      self.pos[lane] = t0 + steps
    f = lambda a, dt=torch.float32: torch.from_numpy(np.stack(a)).to(dt)  # noqa: E731
    inputs = (f(mus), f(pres), f(us, torch.long), f(ls, torch.long), f(sw))
    return inputs, (f(tu, torch.long), f(tl, torch.long)), torch.from_numpy(fresh)

  def snapshot(self) -> dict:
    return {"clip": list(self.clip), "pos": list(self.pos), "style": list(self.style)}

  def restore(self, snap: dict) -> None:
    self.clip, self.pos, self.style = list(snap["clip"]), list(snap["pos"]), list(snap["style"])


def detach(state: dict | None) -> dict | None:
  """The carried state without its graph (gradients stay inside one window)."""
  if state is None:
    return None
  return {blk: {n: x.detach() for n, x in st.items()} for blk, st in state.items()}


def reset_rows(state: dict | None, fresh: torch.Tensor) -> dict | None:
  """The state with the rows in `fresh` (B,) bool set to a song's start: Mamba states zero, KV caches
  invalid (Danceba.forward_with_state's formats)."""
  if state is None or not bool(fresh.any()):
    return state
  out = {}
  for blk, st in state.items():
    if "valid" in st:
      out[blk] = dict(st, valid=st["valid"] & ~fresh[:, None])
    else:
      keep = (~fresh).to(st["ssm"].dtype)
      out[blk] = {"conv": st["conv"] * keep[:, None, None], "ssm": st["ssm"] * keep[:, None, None]}
  return out
