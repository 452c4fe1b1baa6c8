"""Pose VQ-VAE: non-causal encoder (downsampling 4), EMA codebook, causal decoder (one code -> 4 frames).

The decoder is defined as an op list (docs/model.md section 7) and run from that list both here and in the
engine, so the list exported in the weights file is, by construction, what was trained. ``decode`` runs a
whole code sequence; ``DecoderStream`` runs it one code at a time with per-conv state (the engine's form).
"""
from __future__ import annotations

import torch
from torch import nn
import torch.nn.functional as F

from training.model.config import VQConfig


def _conv(cin: int, cout: int, k: int, dilation: int = 1, stride: int = 1) -> nn.Conv1d:
  return nn.Conv1d(cin, cout, k, stride=stride, dilation=dilation)


class Encoder(nn.Module):
  """(B, T, in_dim) -> (B, T/4, code_dim). Symmetric padding (looks ahead); T must be a multiple of 4."""

  def __init__(self, cfg: VQConfig):
    super().__init__()
    w = cfg.width
    self.convs = nn.ModuleList()
    self.ops: list[dict] = []

    def conv(cin, cout, k, dilation=1, stride=1, pad=0):
      self.ops.append({"op": "conv", "idx": len(self.convs), "dilation": dilation, "stride": stride,
                       "pad": pad})
      self.convs.append(_conv(cin, cout, k, dilation, stride))

    conv(cfg.in_dim, w, 3, pad=1)
    self.ops.append({"op": "relu"})
    for _ in range(2):
      conv(w, w, 4, stride=2, pad=1)
      self.ops.append({"op": "relu"})
      for j in range(cfg.n_res):
        d = 3 ** j
        self.ops += [{"op": "res_begin"}, {"op": "relu"}]
        conv(w, w, 3, dilation=d, pad=d)
        self.ops.append({"op": "relu"})
        conv(w, w, 1)
        self.ops.append({"op": "res_end"})
    conv(w, cfg.code_dim, 3, pad=1)

  def forward(self, x: torch.Tensor) -> torch.Tensor:
    h = x.transpose(1, 2)
    stack = []
    for op in self.ops:
      kind = op["op"]
      if kind == "conv":
        h = self.convs[op["idx"]](F.pad(h, (op["pad"], op["pad"])))
      elif kind == "relu":
        h = F.relu(h)
      elif kind == "res_begin":
        stack.append(h)
      elif kind == "res_end":
        h = stack.pop() + h
    return h.transpose(1, 2)


class Decoder(nn.Module):
  """Causal: codes' vectors (B, T, code_dim) -> frames (B, 4T, out_dim) (normalised pose)."""

  def __init__(self, cfg: VQConfig):
    super().__init__()
    w = cfg.width
    self.convs = nn.ModuleList()
    self.ops: list[dict] = [{"op": "embed_codes"}]

    def conv(cin, cout, k, dilation=1):
      self.ops.append({"op": "conv", "idx": len(self.convs), "dilation": dilation})
      self.convs.append(_conv(cin, cout, k, dilation))

    def res_blocks():
      for j in range(cfg.n_res):
        self.ops += [{"op": "res_begin"}, {"op": "relu"}]
        conv(w, w, 3, dilation=3 ** j)
        self.ops.append({"op": "relu"})
        conv(w, w, 1)
        self.ops.append({"op": "res_end"})

    conv(cfg.code_dim, w, 3)
    self.ops.append({"op": "relu"})
    res_blocks()
    for _ in range(2):
      self.ops.append({"op": "upsample2"})
      conv(w, w, 3)
      self.ops.append({"op": "relu"})
      res_blocks()
    conv(w, cfg.in_dim, 3)

  def left_context(self, idx: int) -> int:
    c = self.convs[idx]
    return (c.kernel_size[0] - 1) * c.dilation[0]

  def forward(self, z: torch.Tensor) -> torch.Tensor:
    h = z.transpose(1, 2)
    stack = []
    for op in self.ops[1:]:
      kind = op["op"]
      if kind == "conv":
        h = self.convs[op["idx"]](F.pad(h, (self.left_context(op["idx"]), 0)))
      elif kind == "relu":
        h = F.relu(h)
      elif kind == "res_begin":
        stack.append(h)
      elif kind == "res_end":
        h = stack.pop() + h
      elif kind == "upsample2":
        h = h.repeat_interleave(2, dim=-1)
    return h.transpose(1, 2)


class DecoderStream:
  """Streaming decoder: push one code vector (B, code_dim), get 4 frames (B, 4, out_dim).

  State: for each conv, its last (k-1)*dilation inputs (zeros before the start), exactly what the engine
  keeps.
  """

  def __init__(self, dec: Decoder, batch: int):
    self.dec = dec
    self.buf = {}
    for op in dec.ops:
      if op["op"] == "conv":
        c = dec.convs[op["idx"]]
        self.buf[op["idx"]] = torch.zeros(batch, c.in_channels, dec.left_context(op["idx"]))

  @torch.no_grad()
  def push(self, zvec: torch.Tensor) -> torch.Tensor:
    h = zvec.unsqueeze(-1)  # (B, C, 1)
    stack = []
    for op in self.dec.ops[1:]:
      kind = op["op"]
      if kind == "conv":
        i = op["idx"]
        full = torch.cat([self.buf[i], h], dim=-1)
        keep = self.dec.left_context(i)
        self.buf[i] = full[:, :, full.shape[-1] - keep:] if keep else full[:, :, :0]
        h = self.dec.convs[i](full)
      elif kind == "relu":
        h = F.relu(h)
      elif kind == "res_begin":
        stack.append(h)
      elif kind == "res_end":
        h = stack.pop() + h
      elif kind == "upsample2":
        h = h.repeat_interleave(2, dim=-1)
    return h.transpose(1, 2)


class Quantizer(nn.Module):
  """EMA codebook (K, code_dim) with dead-code reset; straight-through gradients."""

  def __init__(self, k: int, dim: int, decay: float):
    super().__init__()
    self.k, self.dim, self.decay = k, dim, decay
    self.register_buffer("codebook", torch.randn(k, dim) * 0.1)
    self.register_buffer("ema_count", torch.ones(k))
    self.register_buffer("ema_sum", self.codebook.clone())
    self.register_buffer("initialised", torch.tensor(0))

  def nearest(self, z: torch.Tensor) -> torch.Tensor:
    flat = z.reshape(-1, self.dim)
    d = (flat.pow(2).sum(1, keepdim=True) - 2 * flat @ self.codebook.t()
         + self.codebook.pow(2).sum(1)[None])
    return d.argmin(1).view(z.shape[:-1])

  def forward(self, z: torch.Tensor):
    """z (B, T, D) -> (zq straight-through, codes (B,T), commitment loss)."""
    flat = z.detach().reshape(-1, self.dim)
    if self.training and not bool(self.initialised):
      idx = torch.randint(0, flat.shape[0], (self.k,))
      self.codebook.copy_(flat[idx])
      self.ema_sum.copy_(flat[idx])
      self.ema_count.fill_(1.0)
      self.initialised.fill_(1)
    codes = self.nearest(z)
    zq = self.codebook[codes]
    if self.training:
      with torch.no_grad():
        onehot = F.one_hot(codes.reshape(-1), self.k).float()
        count = onehot.sum(0)
        self.ema_count.mul_(self.decay).add_(count, alpha=1 - self.decay)
        self.ema_sum.mul_(self.decay).add_(onehot.t() @ flat, alpha=1 - self.decay)
        n = self.ema_count.sum()
        smoothed = (self.ema_count + 1e-5) / (n + self.k * 1e-5) * n
        self.codebook.copy_(self.ema_sum / smoothed[:, None])
        dead = self.ema_count < 1e-2 * max(1.0, float(flat.shape[0]) / self.k)
        n_dead = int(dead.sum())
        if n_dead:
          idx = torch.randint(0, flat.shape[0], (n_dead,))
          self.codebook[dead] = flat[idx]
          self.ema_sum[dead] = flat[idx]
          self.ema_count[dead] = 1.0
    commit = F.mse_loss(z, zq.detach())
    return z + (zq - z).detach(), codes, commit


class PoseVQVAE(nn.Module):
  """One body part. Works on normalised features; ``pose_mean``/``pose_std`` are stored for export."""

  def __init__(self, cfg: VQConfig):
    super().__init__()
    self.cfg = cfg
    self.register_buffer("pose_mean", torch.zeros(cfg.in_dim))
    self.register_buffer("pose_std", torch.ones(cfg.in_dim))
    self.encoder = Encoder(cfg)
    self.quantizer = Quantizer(cfg.codebook_size, cfg.code_dim, cfg.ema_decay)
    self.decoder = Decoder(cfg)

  def normalise(self, x):
    return (x - self.pose_mean) / self.pose_std

  def denormalise(self, y):
    return y * self.pose_std + self.pose_mean

  def forward(self, x_norm: torch.Tensor):
    """x_norm (B, T, in_dim) -> (recon (B,T,in_dim), codes (B,T/4), commitment loss)."""
    z = self.encoder(x_norm)
    zq, codes, commit = self.quantizer(z)
    return self.decoder(zq), codes, commit

  @torch.no_grad()
  def encode(self, x_norm: torch.Tensor) -> torch.Tensor:
    return self.quantizer.nearest(self.encoder(x_norm))

  @torch.no_grad()
  def decode_codes(self, codes: torch.Tensor) -> torch.Tensor:
    """codes (B, T) -> normalised frames (B, 4T, in_dim)."""
    return self.decoder(self.quantizer.codebook[codes])
