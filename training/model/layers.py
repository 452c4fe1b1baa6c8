"""Small building blocks shared by the TGCA and PMMM blocks (docs/model.md sections 3-5)."""
from __future__ import annotations

import torch
from torch import nn
import torch.nn.functional as F


class RMSNorm(nn.Module):
  """y = x / sqrt(mean(x^2) + eps) * weight, over the last dim."""

  def __init__(self, dim: int, eps: float = 1e-5):
    super().__init__()
    self.eps = eps
    self.weight = nn.Parameter(torch.ones(dim))

  def forward(self, x: torch.Tensor) -> torch.Tensor:
    return x * torch.rsqrt(x.pow(2).mean(-1, keepdim=True) + self.eps) * self.weight


class GatedMLP(nn.Module):
  """W_down (SiLU(W_gate h) * W_up h), no biases."""

  def __init__(self, d: int, d_ff: int):
    super().__init__()
    self.gate = nn.Linear(d, d_ff, bias=False)
    self.up = nn.Linear(d, d_ff, bias=False)
    self.down = nn.Linear(d_ff, d, bias=False)

  def forward(self, h: torch.Tensor) -> torch.Tensor:
    return self.down(F.silu(self.gate(h)) * self.up(h))


class ResidualDropout(nn.Dropout):
  """Dropout on a residual branch's output, for training only: p is 0 unless ``set_residual_dropout``
  raises it, and eval mode (export, the streaming form, the engine) is always the identity. Not part of
  the weights file."""

  def __init__(self):
    super().__init__(0.0)


def set_residual_dropout(model: nn.Module, p: float) -> int:
  """Sets every ResidualDropout of ``model`` to rate p; returns how many there are."""
  n = 0
  for m in model.modules():
    if isinstance(m, ResidualDropout):
      m.p = float(p)
      n += 1
  return n


class StyleModulation(nn.Module):
  """SGMD style modulation: x + x / (||x|| * r + 1e-6) * (W sv + b), per token.

  ``sv`` has shape (B, d_s) and is broadcast over every token of the batch row.
  """

  def __init__(self, d: int, d_s: int, r: float):
    super().__init__()
    self.r = r
    self.proj = nn.Linear(d_s, d)
    nn.init.zeros_(self.proj.weight)
    nn.init.zeros_(self.proj.bias)

  def forward(self, x: torch.Tensor, sv: torch.Tensor) -> torch.Tensor:
    scale = self.proj(sv)  # (B, d)
    while scale.dim() < x.dim():
      scale = scale.unsqueeze(1)
    return x + x / (x.norm(dim=-1, keepdim=True) * self.r + 1e-6) * scale


class PreEmbedding(nn.Module):
  """phi = ReLU(BatchNorm(W_pre p + b_pre)); BatchNorm folds into (bn_scale, bn_shift) at export."""

  def __init__(self, pre_dim: int, d: int):
    super().__init__()
    self.linear = nn.Linear(pre_dim, d)
    self.bn = nn.BatchNorm1d(d)

  def forward(self, p: torch.Tensor) -> torch.Tensor:
    y = self.linear(p)
    shape = y.shape
    y = self.bn(y.reshape(-1, shape[-1])).reshape(shape)
    return F.relu(y)

  def folded(self) -> tuple[torch.Tensor, torch.Tensor]:
    """Returns (bn_scale, bn_shift) of the inference-mode BatchNorm as an affine map."""
    bn = self.bn
    scale = bn.weight / torch.sqrt(bn.running_var + bn.eps)
    shift = bn.bias - bn.running_mean * scale
    return scale.detach(), shift.detach()
