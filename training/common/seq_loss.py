"""The sequence model's objective and its validation figures: the cross-entropy of the next codes, the
training-only multi-step heads, the loss over whole songs with the state carried, and the validation report
every seq run logs (the loss with the true music, with another song's music, their gap, the song loss).

    v = validation(model, val_toks, cfg)
    # {"val_loss", "val_loss_wrong_music", "music_gap", "val_loss_song"}: the figures of the seq log and curves
"""
from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from training.common.tokens import make_batch


def code_loss(lu, ll, targets, reduction: str = "mean") -> torch.Tensor:
  """Cross-entropy of the upper and lower logits against the target codes, averaged over the two."""
  return 0.5 * (F.cross_entropy(lu.flatten(0, 1), targets[0].flatten(), reduction=reduction) +
                F.cross_entropy(ll.flatten(0, 1), targets[1].flatten(), reduction=reduction))


def loss_of(model, inputs, targets) -> torch.Tensor:
  lu, ll = model(*inputs)
  return code_loss(lu, ll, targets)


class AuxHeads(torch.nn.Module):
  """Training-only heads that read the sequence model's final hidden state (norm_f) at step t and predict
  the codes of steps t + 2 .. t + J (the model's own heads predict t + 1): multi-step prediction, so the
  state carries where the dance goes over the next J periods, not only the next code. Not exported."""

  def __init__(self, d_model: int, codebook_size: int, steps: int):
    super().__init__()
    self.steps = steps
    self.upper = torch.nn.ModuleList(torch.nn.Linear(d_model, codebook_size, bias=False)
                                     for _ in range(steps - 1))
    self.lower = torch.nn.ModuleList(torch.nn.Linear(d_model, codebook_size, bias=False)
                                     for _ in range(steps - 1))

  def loss(self, y: torch.Tensor, targets) -> torch.Tensor:
    """y (B, T, 3, d): the final hidden state; targets: make_batch's (next codes (B, T) per part). Mean over
    j = 2 .. J of code_loss of the j-steps-ahead heads, on the positions whose target is in the window."""
    total = y.new_zeros(())
    for j in range(2, self.steps + 1):
      h = y[:, :y.shape[1] - j + 1]
      total = total + code_loss(self.upper[j - 2](h[..., 1, :]), self.lower[j - 2](h[..., 2, :]),
                                (targets[0][:, j - 1:], targets[1][:, j - 1:]))
    return total / (self.steps - 1)


@torch.no_grad()
def song_loss(model, toks, cfg, window: int = 128) -> float:
  """Loss over whole songs from their first step, the state carried (the engine's condition): each song's
  codes with BOS at step 0, its music shifted by the music lookahead, its own style; mean over all steps."""
  s, k = cfg.music_lookahead_steps, cfg.codebook_size
  total, count = 0.0, 0
  for t in toks:
    n = len(t["upper"]) - s - 1
    if n < 1:
      continue
    u = torch.as_tensor(np.asarray(t["upper"][:n])).long().clone()[None]
    l = torch.as_tensor(np.asarray(t["lower"][:n])).long().clone()[None]
    u[0, 0] = l[0, 0] = k
    music = torch.as_tensor(np.asarray(t["music"][s:s + n])).float()[None]
    pre = torch.as_tensor(np.asarray(t["pre"][s:s + n])).float()[None]
    targets = (torch.as_tensor(np.asarray(t["upper"][1:n + 1])).long()[None],
               torch.as_tensor(np.asarray(t["lower"][1:n + 1])).long()[None])
    sw = torch.zeros(1, cfg.n_styles + 1)
    sw[0, t["style"]] = 1
    state = None
    for a in range(0, n, window):
      e = min(n, a + window)
      lu, ll, state = model.forward_with_state(music[:, a:e], pre[:, a:e], u[:, a:e], l[:, a:e], sw, state)
      total += float(code_loss(lu, ll, (targets[0][:, a:e], targets[1][:, a:e]), reduction="sum"))
      count += e - a
  return total / max(count, 1)


@torch.no_grad()
def validation(model, val_toks, cfg, n_batches=6) -> dict:
  """Loss with the true music and with another validation song's music (same windows): the gap; and the
  loss over whole songs with the state carried (song_loss)."""
  was_training = model.training
  model.eval()
  wrong = val_toks[1:] + val_toks[:1]
  out = {"true": [], "wrong": []}
  for key, mf in (("true", None), ("wrong", wrong)):
    rng = np.random.default_rng(123)
    for _ in range(n_batches):
      inputs, targets = make_batch(val_toks, cfg, rng, music_from=mf)
      out[key].append(float(loss_of(model, inputs, targets)))
  song = song_loss(model, val_toks, cfg)
  model.train(was_training)
  vt, vw = float(np.mean(out["true"])), float(np.mean(out["wrong"]))
  return {"val_loss": vt, "val_loss_wrong_music": vw, "music_gap": vw - vt, "val_loss_song": song}
