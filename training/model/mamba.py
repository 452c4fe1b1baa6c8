"""Mamba v1 in plain torch (no CUDA kernels), and the PMMM block built on it.

``forward`` runs a whole sequence (training; the scan is a loop over time, exact, no log-space tricks);
``step`` runs one token with the recurrent state (conv inputs + SSM state), which is the engine's form.
Both compute exactly the arithmetic of docs/model.md section 5.
"""
from __future__ import annotations

import math

import torch
from torch import nn
import torch.nn.functional as F

from training.model.layers import GatedMLP, ResidualDropout, RMSNorm, StyleModulation


class Mamba(nn.Module):
  def __init__(self, d: int, d_state: int = 16, d_conv: int = 4, expand: int = 2):
    super().__init__()
    self.d, self.d_state, self.d_conv = d, d_state, d_conv
    self.d_inner = expand * d
    self.dt_rank = math.ceil(d / 16)
    self.in_proj = nn.Linear(d, 2 * self.d_inner, bias=False)
    self.conv_w = nn.Parameter(torch.empty(self.d_inner, d_conv))
    self.conv_b = nn.Parameter(torch.zeros(self.d_inner))
    nn.init.uniform_(self.conv_w, -1 / math.sqrt(d_conv), 1 / math.sqrt(d_conv))
    self.x_proj = nn.Linear(self.d_inner, self.dt_rank + 2 * d_state, bias=False)
    self.dt_proj = nn.Linear(self.dt_rank, self.d_inner)
    # dt initialised log-uniform in [1e-3, 1e-1] through the inverse softplus, as in Mamba.
    dt = torch.exp(torch.rand(self.d_inner) * (math.log(0.1) - math.log(1e-3)) + math.log(1e-3))
    with torch.no_grad():
      self.dt_proj.bias.copy_(dt + torch.log(-torch.expm1(-dt)))
      nn.init.uniform_(self.dt_proj.weight, -self.dt_rank ** -0.5, self.dt_rank ** -0.5)
    self.A_log = nn.Parameter(torch.log(torch.arange(1, d_state + 1).float()).repeat(self.d_inner, 1))
    self.D = nn.Parameter(torch.ones(self.d_inner))
    self.out_proj = nn.Linear(self.d_inner, d, bias=False)

  def _ssm_inputs(self, c: torch.Tensor):
    dbc = self.x_proj(c)
    dt_in, b, cc = torch.split(dbc, [self.dt_rank, self.d_state, self.d_state], dim=-1)
    dt = F.softplus(self.dt_proj(dt_in))
    return dt, b, cc

  def forward(self, h: torch.Tensor) -> torch.Tensor:
    """h (B, T, d) -> (B, T, d), state starting at zero."""
    return self.forward_with_state(h, None)[0]

  def forward_with_state(self, h: torch.Tensor, state: dict | None) -> tuple[torch.Tensor, dict]:
    """h (B, T, d) -> (B, T, d) and the state after the last step, starting from `state` (``step``'s
    format: the last d_conv-1 conv inputs and the SSM state; None = zeros): a long sequence run window by
    window with the state carried equals the whole sequence run at once (training with carried state)."""
    bsz, t, _ = h.shape
    xi, zg = self.in_proj(h).chunk(2, dim=-1)
    prev = h.new_zeros(bsz, self.d_inner, self.d_conv - 1) if state is None else state["conv"]
    xp = torch.cat([prev, xi.transpose(1, 2)], dim=-1)  # (B, d_inner, d_conv - 1 + T)
    c = F.conv1d(xp, self.conv_w.unsqueeze(1), self.conv_b, groups=self.d_inner).transpose(1, 2)
    c = F.silu(c)
    dt, b, cc = self._ssm_inputs(c)
    a = -torch.exp(self.A_log)  # (d_inner, d_state)
    decay = torch.exp(dt.unsqueeze(-1) * a)  # (B, T, d_inner, d_state)
    drive = (dt * c).unsqueeze(-1) * b.unsqueeze(2)  # (B, T, d_inner, d_state)
    hs = h.new_zeros(bsz, self.d_inner, self.d_state) if state is None else state["ssm"]
    states = []
    # unbind (not decay[:, i]) so that the backward pass stacks gradients instead of scattering each step
    # into a full-size zero tensor (which made the loop quadratic in T).
    for dec_i, drv_i in zip(decay.unbind(1), drive.unbind(1)):
      hs = dec_i * hs + drv_i
      states.append(hs)
    y = torch.einsum("btin,btn->bti", torch.stack(states, dim=1), cc) + self.D * c
    return self.out_proj(y * F.silu(zg)), {"conv": xp[:, :, xp.shape[-1] - (self.d_conv - 1):], "ssm": hs}

  def step(self, h: torch.Tensor, state: dict | None) -> tuple[torch.Tensor, dict]:
    """h (B, d) one token -> (B, d). state: 'conv' (B, d_inner, d_conv-1), 'ssm' (B, d_inner, d_state)."""
    bsz = h.shape[0]
    if state is None:
      state = {"conv": h.new_zeros(bsz, self.d_inner, self.d_conv - 1),
               "ssm": h.new_zeros(bsz, self.d_inner, self.d_state)}
    xi, zg = self.in_proj(h).chunk(2, dim=-1)
    window = torch.cat([state["conv"], xi.unsqueeze(-1)], dim=-1)  # (B, d_inner, d_conv)
    c = F.silu((window * self.conv_w).sum(-1) + self.conv_b)
    dt, b, cc = self._ssm_inputs(c)
    a = -torch.exp(self.A_log)
    hs = torch.exp(dt.unsqueeze(-1) * a) * state["ssm"] + (dt * c).unsqueeze(-1) * b.unsqueeze(1)
    y = torch.einsum("bin,bn->bi", hs, cc) + self.D * c
    out = self.out_proj(y * F.silu(zg))
    return out, {"conv": window[:, :, 1:], "ssm": hs}


class PMMMBlock(nn.Module):
  """One stream's block: style modulation, x += Mamba(RMSNorm(x)), x += GatedMLP(RMSNorm(x))."""

  def __init__(self, d: int, d_state: int, d_conv: int, expand: int, d_s: int, r: float):
    super().__init__()
    self.style = StyleModulation(d, d_s, r)
    self.norm1 = RMSNorm(d)
    self.mamba = Mamba(d, d_state, d_conv, expand)
    self.norm2 = RMSNorm(d)
    self.mlp = GatedMLP(d, 2 * d)
    self.drop = ResidualDropout()

  def forward(self, x: torch.Tensor, sv: torch.Tensor) -> torch.Tensor:  # x (B, T, d)
    return self.forward_with_state(x, sv, None)[0]

  def forward_with_state(self, x: torch.Tensor, sv: torch.Tensor, state: dict | None):  # x (B, T, d)
    x = self.style(x, sv)
    m, state = self.mamba.forward_with_state(self.norm1(x), state)
    x = x + self.drop(m)
    return x + self.drop(self.mlp(self.norm2(x))), state

  def step(self, x: torch.Tensor, sv: torch.Tensor, state: dict | None):  # x (B, d)
    x = self.style(x, sv)
    m, state = self.mamba.step(self.norm1(x), state)
    x = x + m
    return x + self.mlp(self.norm2(x)), state
