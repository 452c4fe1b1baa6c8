"""SGMD: the style-guided motion diffusion editor (docs/diffusion.md, the exact definition; the second paper,
section III). A transformer denoiser over one window of motion (150 frames = 5 s), conditioned on the
window's music (the engine's features), a style vector (Style Modulation) and the diffusion step (FiLM).
It predicts the clean motion x0 from the noised x_t (directly, or through v: SGMDConfig.prediction).

    model = SGMD(SGMDConfig())
    x0_hat = model(x_t, t, music, style_w, keep_music)   # (B, N, D), (B,), (B, N/2, 2 M), (B, S+1), (B,)

Every tensor name and op here is mirrored by the engine (engine/diffusion/); change both with the
contract.
"""
from __future__ import annotations

import dataclasses
import math

import torch
from torch import nn
import torch.nn.functional as F


@dataclasses.dataclass
class SGMDConfig:
  feature_dim: int = 108        # F: the engine's music features per frame (docs/features.md)
  pre_dim: int = 128            # P: PRE per frame
  pose_dim: int = 78            # D: the motion vector per frame (docs/diffusion.md section 2)
  frames: int = 150             # N: frames per window (5 s at 30 fps)
  frames_per_token: int = 2     # motion and music tokens each cover this many frames
  d_model: int = 192
  n_heads: int = 4
  n_layers: int = 4             # decoder blocks
  n_music_layers: int = 2       # music encoder blocks
  n_styles: int = 6
  style_dim: int = 64
  style_mod_r: float = 0.0      # 0 = d_model^-0.5
  diffusion_steps: int = 1000   # T (the training schedule; sampling uses a subset)
  prediction: str = "x0"        # what the output layer gives: "x0", or "v" (x0 = sqrt(abar) x_t - sqrt(1-abar) v)
  dropout: float = 0.1          # training only

  def __post_init__(self):
    if self.style_mod_r <= 0:
      self.style_mod_r = self.d_model ** -0.5
    if self.frames % self.frames_per_token:
      raise ValueError("frames must be a multiple of frames_per_token")
    if self.d_model % self.n_heads or self.d_model % 2:
      raise ValueError("d_model must be even and a multiple of n_heads")
    if self.prediction not in ("x0", "v"):
      raise ValueError(f"prediction must be 'x0' or 'v', got {self.prediction!r}")

  @property
  def tokens(self) -> int:
    return self.frames // self.frames_per_token

  @property
  def music_dim(self) -> int:
    return self.frames_per_token * (self.feature_dim + self.pre_dim)

  @property
  def d_ff(self) -> int:
    return 4 * self.d_model


def cosine_alphas_cumprod(steps: int, s: float = 0.008) -> torch.Tensor:
  """abar_t for t = 0..steps-1 (Nichol & Dhariwal's cosine schedule, betas clipped to 0.999), float64."""
  x = torch.arange(steps + 1, dtype=torch.float64)
  f = torch.cos(((x / steps) + s) / (1 + s) * math.pi / 2) ** 2
  abar = f / f[0]
  betas = (1 - abar[1:] / abar[:-1]).clamp(max=0.999)
  return torch.cumprod(1 - betas, dim=0)


def timestep_embedding(t: torch.Tensor, d: int) -> torch.Tensor:
  """(B,) steps -> (B, d): [sin(t f_i), cos(t f_i)], f_i = exp(-ln(10000) i / (d/2)), i < d/2."""
  half = d // 2
  freqs = torch.exp(-math.log(10000.0) * torch.arange(half, dtype=torch.float32) / half)
  a = t.float()[:, None] * freqs[None]
  return torch.cat([torch.sin(a), torch.cos(a)], dim=-1)


class Attention(nn.Module):
  """Multi-head attention with biases; q from x, k and v from ctx (= x for self-attention). No mask."""

  def __init__(self, d: int, n_heads: int):
    super().__init__()
    self.h = n_heads
    self.q, self.k, self.v, self.o = (nn.Linear(d, d) for _ in range(4))

  def forward(self, x: torch.Tensor, ctx: torch.Tensor) -> torch.Tensor:
    b, n, d = x.shape
    m = ctx.shape[1]
    dh = d // self.h
    q = self.q(x).view(b, n, self.h, dh).transpose(1, 2)
    k = self.k(ctx).view(b, m, self.h, dh).transpose(1, 2)
    v = self.v(ctx).view(b, m, self.h, dh).transpose(1, 2)
    a = torch.softmax(q @ k.transpose(-1, -2) / math.sqrt(dh), dim=-1) @ v
    return self.o(a.transpose(1, 2).reshape(b, n, d))


class FeedForward(nn.Module):
  """Linear(d, 4d) -> GELU (erf) -> Linear(4d, d), with biases."""

  def __init__(self, d: int, d_ff: int):
    super().__init__()
    self.fc1 = nn.Linear(d, d_ff)
    self.fc2 = nn.Linear(d_ff, d)

  def forward(self, h: torch.Tensor) -> torch.Tensor:
    return self.fc2(F.gelu(self.fc1(h)))


class EncoderBlock(nn.Module):
  """Music encoder: x += SelfAttn(LN1 x); x += FFN(LN2 x)."""

  def __init__(self, cfg: SGMDConfig):
    super().__init__()
    d = cfg.d_model
    self.norm1, self.norm2 = nn.LayerNorm(d), nn.LayerNorm(d)
    self.attn = Attention(d, cfg.n_heads)
    self.ffn = FeedForward(d, cfg.d_ff)
    self.drop = nn.Dropout(cfg.dropout)

  def forward(self, x: torch.Tensor) -> torch.Tensor:
    h = self.norm1(x)
    x = x + self.drop(self.attn(h, h))
    return x + self.drop(self.ffn(self.norm2(x)))


class DecoderBlock(nn.Module):
  """Style Modulation, then self-attention, cross-attention to the music and the FFN, each FiLM-ed by the
  conditioning vector: x += FiLM_k(sub_k(LN_k x)), FiLM(h) = h (1 + scale) + shift."""

  def __init__(self, cfg: SGMDConfig):
    super().__init__()
    d = cfg.d_model
    self.r = cfg.style_mod_r
    self.style = nn.Linear(cfg.style_dim, d)
    nn.init.zeros_(self.style.weight)
    nn.init.zeros_(self.style.bias)
    self.norm1, self.norm2, self.norm3 = nn.LayerNorm(d), nn.LayerNorm(d), nn.LayerNorm(d)
    self.self_attn = Attention(d, cfg.n_heads)
    self.cross_attn = Attention(d, cfg.n_heads)
    self.ffn = FeedForward(d, cfg.d_ff)
    self.film = nn.Linear(d, 6 * d)    # (scale, shift) for the three sub-layers, from SiLU(cond)
    nn.init.zeros_(self.film.weight)
    nn.init.zeros_(self.film.bias)
    self.drop = nn.Dropout(cfg.dropout)

  def forward(self, x: torch.Tensor, music: torch.Tensor, cond: torch.Tensor, sv: torch.Tensor) -> torch.Tensor:
    scale = self.style(sv)[:, None]
    x = x + x / (x.norm(dim=-1, keepdim=True) * self.r + 1e-6) * scale
    f = self.film(F.silu(cond))[:, None].chunk(6, dim=-1)
    h = self.norm1(x)
    x = x + self.drop(self.self_attn(h, h) * (1 + f[0]) + f[1])
    x = x + self.drop(self.cross_attn(self.norm2(x), music) * (1 + f[2]) + f[3])
    return x + self.drop(self.ffn(self.norm3(x)) * (1 + f[4]) + f[5])


class SGMD(nn.Module):
  def __init__(self, cfg: SGMDConfig):
    super().__init__()
    self.cfg = cfg
    d, n = cfg.d_model, cfg.tokens
    self.motion_in = nn.Linear(cfg.frames_per_token * cfg.pose_dim, d)
    self.motion_pos = nn.Parameter(torch.randn(n, d) * 0.02)
    self.music_in = nn.Linear(cfg.music_dim, d)
    self.music_pos = nn.Parameter(torch.randn(n, d) * 0.02)
    self.music_blocks = nn.ModuleList(EncoderBlock(cfg) for _ in range(cfg.n_music_layers))
    self.music_norm = nn.LayerNorm(d)
    self.music_null = nn.Parameter(torch.randn(n, d) * 0.02)   # the music tokens when music is dropped
    self.music_pool = nn.Linear(d, d)
    self.time_fc1 = nn.Linear(d, 4 * d)
    self.time_fc2 = nn.Linear(4 * d, d)
    self.style_table = nn.Parameter(torch.randn(cfg.n_styles + 1, cfg.style_dim) * 0.5)  # last row: none
    self.blocks = nn.ModuleList(DecoderBlock(cfg) for _ in range(cfg.n_layers))
    self.norm_f = nn.LayerNorm(d)
    self.out = nn.Linear(d, cfg.frames_per_token * cfg.pose_dim)
    nn.init.zeros_(self.out.bias)
    self.register_buffer("alphas_cumprod", cosine_alphas_cumprod(cfg.diffusion_steps).float(), persistent=False)

  def encode_music(self, music: torch.Tensor, keep: torch.Tensor) -> torch.Tensor:
    """music (B, N, music_dim) normalised -> music tokens (B, N, d); rows with keep False get music_null."""
    x = self.music_in(music) + self.music_pos
    for blk in self.music_blocks:
      x = blk(x)
    x = self.music_norm(x)
    return torch.where(keep[:, None, None], x, self.music_null.expand_as(x))

  def forward(self, x_t: torch.Tensor, t: torch.Tensor, music: torch.Tensor, style_w: torch.Tensor,
              keep_music: torch.Tensor) -> torch.Tensor:
    c = self.encode_music(music, keep_music)
    return self.denoise(x_t, t, c, style_w)

  def denoise(self, x_t: torch.Tensor, t: torch.Tensor, c: torch.Tensor, style_w: torch.Tensor) -> torch.Tensor:
    """The decoder on encoded music tokens c (B, N, d)."""
    b, nf, dd = x_t.shape
    cfg = self.cfg
    x = self.motion_in(x_t.reshape(b, cfg.tokens, cfg.frames_per_token * dd)) + self.motion_pos
    te = self.time_fc2(F.silu(self.time_fc1(timestep_embedding(t, cfg.d_model))))
    cond = te + self.music_pool(c.mean(dim=1))
    sv = style_w @ self.style_table
    for blk in self.blocks:
      x = blk(x, c, cond, sv)
    y = self.out(self.norm_f(x)).reshape(b, nf, dd)
    if cfg.prediction == "v":  # the v parameterisation: at low noise x0 is x_t by construction
      abar = self.alphas_cumprod[t][:, None, None]
      return abar.sqrt() * x_t - (1 - abar).sqrt() * y
    return y
