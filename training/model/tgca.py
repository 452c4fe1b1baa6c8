"""TGCA: gated cross-conditional causal attention over the three interleaved streams.

Tokens are ordered per step as (music, upper, lower). A token of step t attends to every token of steps
t' with t - W < t' <= t, with the ALiBi bias -slope_h * (t - t') (docs/model.md section 5).
Two forms with identical arithmetic: ``forward`` over a whole window (training) and ``step`` with a KV
cache of the last W steps (streaming; the engine's form).
"""
from __future__ import annotations

import math

import torch
from torch import nn
import torch.nn.functional as F

from training.model.layers import GatedMLP, ResidualDropout, RMSNorm, StyleModulation


def alibi_slopes(n_heads: int) -> torch.Tensor:
  return torch.tensor([2.0 ** (-8.0 * (h + 1) / n_heads) for h in range(n_heads)])


def window_bias(n_steps: int, window: int, n_heads: int, step_offset: int = 0) -> torch.Tensor:
  """Additive attention bias (H, 3T, 3T): ALiBi in steps inside the window, -inf outside."""
  step = torch.arange(n_steps).repeat_interleave(3)
  dist = (step[:, None] - step[None, :]).float()  # query step - key step
  allowed = (dist >= 0) & (dist < window)
  slopes = alibi_slopes(n_heads)
  bias = -slopes[:, None, None] * dist[None]
  return bias.masked_fill(~allowed[None], float("-inf"))


class TGCABlock(nn.Module):
  """Shared by all streams. State for ``step``: dict with 'k', 'v' of shape (B, H, 3*n, d_head)."""

  def __init__(self, d: int, n_heads: int, window: int, d_s: int, r: float, use_gate: bool = True):
    super().__init__()
    assert d % n_heads == 0
    self.d, self.n_heads, self.window, self.use_gate = d, n_heads, window, use_gate
    self.d_head = d // n_heads
    self.style = StyleModulation(d, d_s, r)
    self.norm1 = RMSNorm(d)
    self.w_in = nn.Linear(d, d, bias=False)
    self.w_q = nn.Linear(d, d, bias=False)
    self.w_k = nn.Linear(d, d, bias=False)
    self.w_v = nn.Linear(d, d, bias=False)
    self.w_g = nn.Linear(d, d, bias=False)
    self.w_o = nn.Linear(d, d, bias=False)
    self.norm2 = RMSNorm(d)
    self.mlp = GatedMLP(d, 2 * d)
    self.drop = ResidualDropout()
    self.register_buffer("slopes", alibi_slopes(n_heads), persistent=False)

  def _heads(self, t: torch.Tensor) -> torch.Tensor:  # (B, N, d) -> (B, H, N, dh)
    b, n, _ = t.shape
    return t.view(b, n, self.n_heads, self.d_head).transpose(1, 2)

  def _qkv(self, h: torch.Tensor):
    z = F.silu(self.w_in(h))
    return self._heads(self.w_q(z)), self._heads(self.w_k(z)), self._heads(self.w_v(z))

  def _finish(self, x, h, a, trace, prefix):
    gate = F.silu(self.w_g(h)) if self.use_gate else 1.0
    x = x + self.drop(self.w_o(a * gate))
    if trace is not None:
      trace[prefix + ".attn_out"] = x
    x = x + self.drop(self.mlp(self.norm2(x)))
    return x

  def forward(self, x: torch.Tensor, sv: torch.Tensor, trace: dict | None = None,
              prefix: str = "") -> torch.Tensor:
    """x (B, T, 3, d) -> (B, T, 3, d), whole window from step 0."""
    return self.forward_with_state(x, sv, None, trace, prefix)[0]

  def forward_with_state(self, x: torch.Tensor, sv: torch.Tensor, state: dict | None,
                         trace: dict | None = None, prefix: str = "") -> tuple[torch.Tensor, dict]:
    """x (B, T, 3, d) -> (B, T, 3, d) and the KV cache after the window, the window's steps attending also
    to the cached steps before it. `state`: ``step``'s format ('k', 'v' (B, H, 3n, d_head) of the last n
    <= W-1 steps) plus an optional 'valid' (B, 3n) bool, False for a batch row whose cache holds nothing
    (a row that starts a song while others continue); None = no steps before."""
    b, t, _, d = x.shape
    x = self.style(x.reshape(b, 3 * t, d), sv)
    h = self.norm1(x)
    q, k, v = self._qkv(h)
    n = 0
    valid = torch.ones(b, 3 * t, dtype=torch.bool, device=x.device)
    if state is not None and state["k"].shape[2] > 0:
      n = state["k"].shape[2] // 3
      k = torch.cat([state["k"], k], dim=2)
      v = torch.cat([state["v"], v], dim=2)
      prev = state.get("valid")
      if prev is None:
        prev = torch.ones(b, 3 * n, dtype=torch.bool, device=x.device)
      valid = torch.cat([prev, valid], dim=1)
    bias = window_bias(n + t, self.window, self.n_heads).to(x)[:, 3 * n:]  # queries: the window's steps
    scores = q @ k.transpose(-1, -2) / math.sqrt(self.d_head) + bias
    if not bool(valid.all()):  # only rows that start a song while others continue need the mask
      scores = scores.masked_fill(~valid[:, None, None, :], float("-inf"))
    a = (torch.softmax(scores, dim=-1) @ v).transpose(1, 2).reshape(b, 3 * t, d)
    start = max(0, k.shape[2] - 3 * (self.window - 1))  # the next window sees W-1 past steps
    new_state = {"k": k[:, :, start:], "v": v[:, :, start:], "valid": valid[:, start:]}
    return self._finish(x, h, a, trace, prefix).view(b, t, 3, d), new_state

  def step(self, x: torch.Tensor, sv: torch.Tensor, state: dict | None, trace: dict | None = None,
           prefix: str = "") -> tuple[torch.Tensor, dict]:
    """x (B, 3, d) of one step -> (B, 3, d), updating the KV cache of the last W steps."""
    b, _, d = x.shape
    x = self.style(x, sv)
    h = self.norm1(x)
    q, k, v = self._qkv(h)
    if state is not None:
      k = torch.cat([state["k"], k], dim=2)
      v = torch.cat([state["v"], v], dim=2)
    n_steps = k.shape[2] // 3
    dist = torch.arange(n_steps - 1, -1, -1, device=x.device).repeat_interleave(3).to(x.dtype)
    bias = -self.slopes.to(x)[:, None] * dist[None]  # (H, 3n); all cached steps are inside the window
    att = torch.softmax(q @ k.transpose(-1, -2) / math.sqrt(self.d_head) + bias[:, None, :], dim=-1)
    a = (att @ v).transpose(1, 2).reshape(b, 3, d)
    keep = 3 * (self.window - 1)  # the next step sees W-1 past steps plus itself
    new_state = {"k": k[:, :, -keep:], "v": v[:, :, -keep:]} if keep > 0 else {
        "k": k[:, :, :0], "v": v[:, :, :0]}
    return self._finish(x, h, a, trace, prefix), new_state
