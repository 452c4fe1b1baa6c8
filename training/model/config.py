"""Hyperparameters of the sequence model and the pose VQ-VAEs.

Every field is written into the weights file's metadata (``hyperparameters`` and ``vq``), so the engine
derives every tensor shape from them. See docs/model.md for the math and docs/weights-format.md for names.
"""
from __future__ import annotations

import dataclasses
import math


@dataclasses.dataclass
class SeqConfig:
  """Sizes of the streaming Danceba model (docs/model.md sections 2-5)."""
  feature_dim: int = 108          # F: music feature dims per frame (docs/features.md)
  pre_dim: int = 128              # P: PRE dims per frame
  frames_per_step: int = 4
  codebook_size: int = 512        # K (index K is BOS)
  d_model: int = 128
  n_heads: int = 4
  n_base: int = 2                 # TGCA blocks before the PMMM blocks
  n_head: int = 2                 # PMMM blocks
  attn_window: int = 32           # W, in steps
  d_state: int = 16
  d_conv: int = 4
  expand: int = 2
  n_styles: int = 6               # style rows; row n_styles is "none"
  style_dim: int = 32             # d_s
  style_mod_r: float = 0.0        # 0 -> d_model ** -0.5 (set in __post_init__)
  music_lookahead_steps: int = 0  # s: 0 anticipatory, 1 reactive
  use_pre: bool = True            # ablation: no PRE
  use_gate: bool = True           # ablation: TGCA without the SiLU(W_g h) gate
  shared_mamba: bool = False      # ablation: one PMMM weight set for all three streams

  def __post_init__(self):
    if self.style_mod_r <= 0:
      self.style_mod_r = self.d_model ** -0.5

  @property
  def d_inner(self) -> int:
    return self.expand * self.d_model

  @property
  def dt_rank(self) -> int:
    return math.ceil(self.d_model / 16)

  @property
  def d_ff(self) -> int:
    return 2 * self.d_model

  @property
  def music_dim(self) -> int:
    return self.frames_per_step * self.feature_dim

  def to_dict(self) -> dict:
    d = dataclasses.asdict(self)
    d.update(d_inner=self.d_inner, dt_rank=self.dt_rank, d_ff=self.d_ff, music_dim=self.music_dim)
    return d

  @classmethod
  def from_dict(cls, d: dict) -> "SeqConfig":
    names = {f.name for f in dataclasses.fields(cls)}
    return cls(**{k: v for k, v in d.items() if k in names})


@dataclasses.dataclass
class VQConfig:
  """One pose VQ-VAE (upper or lower body): downsampling 4, causal decoder."""
  in_dim: int = 45                # 45 upper, 31 lower
  width: int = 128
  code_dim: int = 64
  codebook_size: int = 512
  n_res: int = 2                  # residual blocks per resolution
  ema_decay: float = 0.99
  commit_weight: float = 0.02
  path_weight: float = 0.0        # lower body: weight of the integrated root path/heading loss (common.vq_training)
  vel_weight: float = 1.0         # weight of the velocity term of the reconstruction loss (common.vq_training)
  acc_weight: float = 1.0         # weight of the acceleration term (common.vq_training)

  def to_dict(self) -> dict:
    return dataclasses.asdict(self)

  @classmethod
  def from_dict(cls, d: dict) -> "VQConfig":
    names = {f.name for f in dataclasses.fields(cls)}
    return cls(**{k: v for k, v in d.items() if k in names})
