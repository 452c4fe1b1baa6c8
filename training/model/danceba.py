"""The streaming Danceba sequence model (docs/model.md sections 2-6).

Inputs per step t (already shifted by ``music_lookahead_steps`` by the caller, so index t holds m_{t+s}):
  music (.., 4F) raw features of 4 frames, pre (.., P), codes u_t, l_t in [0, K] (K = BOS),
  style weights (B, n_styles + 1) (non-negative, summing to 1; last column is "none").
Outputs: logits of (u_{t+1}, l_{t+1}), each (.., K).

``forward`` runs a whole window in parallel (training); ``forward_with_state`` the same from the state a
previous window left (training with carried state); ``step`` runs one step with carried state (KV caches
and Mamba states). All agree to float rounding (tests/training/test_model_streaming.py).
"""
from __future__ import annotations

import torch
from torch import nn

from training.model.config import SeqConfig
from training.model.layers import PreEmbedding, RMSNorm
from training.model.mamba import PMMMBlock
from training.model.tgca import TGCABlock

STREAMS = ("music", "upper", "lower")


class Danceba(nn.Module):
  def __init__(self, cfg: SeqConfig):
    super().__init__()
    self.cfg = cfg
    d, k = cfg.d_model, cfg.codebook_size
    self.register_buffer("music_mean", torch.zeros(cfg.music_dim))
    self.register_buffer("music_std", torch.ones(cfg.music_dim))
    self.embed_music = nn.Linear(cfg.music_dim, d)
    self.embed_upper = nn.Embedding(k + 1, d)
    self.embed_lower = nn.Embedding(k + 1, d)
    self.embed_stream = nn.Parameter(torch.randn(3, d) * 0.02)
    self.pre = PreEmbedding(cfg.pre_dim, d)
    self.style_table = nn.Parameter(torch.randn(cfg.n_styles + 1, cfg.style_dim) * 0.5)

    def tgca():
      return TGCABlock(d, cfg.n_heads, cfg.attn_window, cfg.style_dim, cfg.style_mod_r, cfg.use_gate)

    def pmmm():
      return PMMMBlock(d, cfg.d_state, cfg.d_conv, cfg.expand, cfg.style_dim, cfg.style_mod_r)

    self.base = nn.ModuleList([tgca() for _ in range(cfg.n_base)])
    n_sets = 1 if cfg.shared_mamba else 3
    self.pmmm = nn.ModuleList([nn.ModuleList([pmmm() for _ in range(n_sets)]) for _ in range(cfg.n_head)])
    self.final = tgca()
    self.norm_f = RMSNorm(d)
    self.head_upper = nn.Linear(d, k, bias=False)
    self.head_lower = nn.Linear(d, k, bias=False)

  # ---- shared pieces -------------------------------------------------------------------------------
  def style_vector(self, style_w: torch.Tensor) -> torch.Tensor:
    return style_w @ self.style_table  # (B, d_s)

  def embed(self, music, pre, u, l):
    """(.., 4F), (.., P), (..), (..) -> (.., 3, d). The codes u, l are indices, or (.., K+1) one-hot rows
    (float, e.g. a straight-through sample: the same values as the lookup, with a gradient into the rows)."""
    xm = self.embed_music((music - self.music_mean) / self.music_std)

    def codes(table: nn.Embedding, c: torch.Tensor) -> torch.Tensor:
      return c @ table.weight if c.is_floating_point() else table(c)
    x = torch.stack([xm, codes(self.embed_upper, u), codes(self.embed_lower, l)], dim=-2)
    if self.cfg.use_pre:
      x = x + self.pre(pre).unsqueeze(-2)
    return x + self.embed_stream

  def _pmmm_set(self, layer: int, stream: int) -> PMMMBlock:
    blocks = self.pmmm[layer]
    return blocks[0] if len(blocks) == 1 else blocks[stream]

  def _heads(self, y):
    return self.head_upper(y[..., 1, :]), self.head_lower(y[..., 2, :])

  # ---- parallel (training) form ----------------------------------------------------------------------
  def forward(self, music, pre, u, l, style_w, trace: dict | None = None):
    """music (B,T,4F), pre (B,T,P), u/l (B,T) long, style_w (B,S+1) -> logits_u, logits_l (B,T,K)."""
    lu, ll, _ = self.forward_with_state(music, pre, u, l, style_w, None, trace)
    return lu, ll

  def forward_with_state(self, music, pre, u, l, style_w, state: dict | None, trace: dict | None = None):
    """``forward`` starting from the state a previous window left (None = the song's start), and the state
    after this window: ``step``'s keys and formats (TGCA: KV cache, plus 'valid'; PMMM: Mamba state), so a
    long sequence run window by window equals it run at once (training with carried state)."""
    state = state or {}
    new_state = {}
    sv = self.style_vector(style_w)
    x = self.embed(music, pre, u, l)
    if trace is not None:
      trace["embed"] = x
    for i, blk in enumerate(self.base):
      x, new_state[f"base{i}"] = blk.forward_with_state(x, sv, state.get(f"base{i}"), trace, f"base{i}")
      if trace is not None:
        trace[f"base{i}"] = x
    for i in range(self.cfg.n_head):
      outs = []
      for s in range(3):
        key = f"pmmm{i}.{s}"
        o, new_state[key] = self._pmmm_set(i, s).forward_with_state(x[:, :, s], sv, state.get(key))
        outs.append(o)
      x = torch.stack(outs, dim=2)
      if trace is not None:
        trace[f"pmmm{i}"] = x
    x, new_state["final"] = self.final.forward_with_state(x, sv, state.get("final"), trace, "final")
    if trace is not None:
      trace["final"] = x
    y = self.norm_f(x)
    if trace is not None:
      trace["norm_f"] = y
    lu, ll = self._heads(y)
    return lu, ll, new_state

  # ---- streaming (engine) form -----------------------------------------------------------------------
  def step(self, music, pre, u, l, style_w, state: dict | None, trace: dict | None = None):
    """One step: music (B,4F), pre (B,P), u/l (B,) -> (logits_u, logits_l) (B,K), new state."""
    state = state or {}
    new_state = {}
    sv = self.style_vector(style_w)
    x = self.embed(music, pre, u, l)
    if trace is not None:
      trace["embed"] = x
    for i, blk in enumerate(self.base):
      x, new_state[f"base{i}"] = blk.step(x, sv, state.get(f"base{i}"), trace, f"base{i}")
      if trace is not None:
        trace[f"base{i}"] = x
    for i in range(self.cfg.n_head):
      outs = []
      for s in range(3):
        key = f"pmmm{i}.{s}"
        o, new_state[key] = self._pmmm_set(i, s).step(x[:, s], sv, state.get(key))
        outs.append(o)
      x = torch.stack(outs, dim=1)
      if trace is not None:
        trace[f"pmmm{i}"] = x
    x, new_state["final"] = self.final.step(x, sv, state.get("final"), trace, "final")
    if trace is not None:
      trace["final"] = x
    y = self.norm_f(x)
    if trace is not None:
      trace["norm_f"] = y
    lu, ll = self._heads(y)
    return lu, ll, new_state


def one_hot_style(batch: int, style: int, n_styles: int) -> torch.Tensor:
  """Style weights (B, n_styles+1) for one style index; -1 or n_styles means "none"."""
  w = torch.zeros(batch, n_styles + 1)
  w[:, n_styles if style < 0 else style] = 1.0
  return w
