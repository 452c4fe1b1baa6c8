"""Batch PRE: the same numbers as the engine's incremental PRE (engine/audio/incremental_pre.h), for training.

Input: the PRE input channels, shape (T, 4), as written by `dance-features --pre-input` (or
extract_features(...)["pre_input"]). Output: (T, 128), row n = PRE of frame n, layout
[channel][bin 1..16][cos, sin]. Definition (docs/features.md):
    D_k(n) = sum_{m=0}^{63} x(n-63+m) exp(-2 pi i k m / 64),  x(n) = 0 for n < 0
    H_k    = 0.5 D_k - 0.25 D_{k-1} - 0.25 D_{k+1}, D_0 := 0
    out    = (Re H_k, Im H_k) / sqrt(|H_k|^2 + eps^2), eps = 1e-3
`pre_batch_numpy` works in float64; `pre_batch_torch` takes a (B, T, C) or (T, C) tensor (any float dtype;
computed in float64, returned in the input dtype), using torch.stft over the same causal frames.
"""
from __future__ import annotations

import numpy as np

WINDOW = 64
FIRST_BIN = 1
NUM_BINS = 16
EPSILON = 1e-3


def _finish_numpy(d: np.ndarray) -> np.ndarray:
    """d: (T, C, NUM_BINS + 2) complex DFT bins 0..17 -> (T, C * NUM_BINS * 2)."""
    d = d.copy()
    d[..., 0] = 0.0
    k = np.arange(FIRST_BIN, FIRST_BIN + NUM_BINS)
    h = 0.5 * d[..., k] - 0.25 * (d[..., k - 1] + d[..., k + 1])
    inv = 1.0 / np.sqrt(np.abs(h) ** 2 + EPSILON ** 2)
    out = np.stack([h.real * inv, h.imag * inv], axis=-1)  # (T, C, bins, 2)
    return out.reshape(out.shape[0], -1)


def pre_batch_numpy(channels: np.ndarray) -> np.ndarray:
    x = np.asarray(channels, dtype=np.float64)
    if x.ndim != 2:
        raise ValueError(f"expected (T, C) channels, got shape {x.shape}")
    t_len, _ = x.shape
    padded = np.concatenate([np.zeros((WINDOW - 1, x.shape[1])), x], axis=0)
    frames = np.lib.stride_tricks.sliding_window_view(padded, WINDOW, axis=0)  # (T, C, WINDOW), oldest first
    assert frames.shape[0] == t_len
    k = np.arange(NUM_BINS + 2)
    m = np.arange(WINDOW)
    basis = np.exp(-2j * np.pi * np.outer(m, k) / WINDOW)  # (WINDOW, bins)
    d = frames @ basis  # (T, C, bins)
    return _finish_numpy(d).astype(np.float32)


def pre_batch_torch(channels):
    """Same as pre_batch_numpy via torch.stft; channels (T, C) or (B, T, C) tensor."""
    import torch

    x = channels
    squeeze = x.dim() == 2
    if squeeze:
        x = x.unsqueeze(0)
    dtype = x.dtype
    b, t_len, c = x.shape
    signal = x.permute(0, 2, 1).reshape(b * c, t_len).to(torch.float64)
    signal = torch.nn.functional.pad(signal, (WINDOW - 1, 0))
    # center=False, hop 1: frame n covers padded[n : n + 64] = x[n-63 .. n], oldest first.
    spec = torch.stft(signal, n_fft=WINDOW, hop_length=1, win_length=WINDOW,
                      window=torch.ones(WINDOW, dtype=torch.float64), center=False, onesided=True,
                      return_complex=True)  # (b*c, 33, T)
    d = spec[:, : NUM_BINS + 2, :].clone()
    d[:, 0, :] = 0
    k = torch.arange(FIRST_BIN, FIRST_BIN + NUM_BINS)
    h = 0.5 * d[:, k, :] - 0.25 * (d[:, k - 1, :] + d[:, k + 1, :])  # (b*c, bins, T)
    inv = 1.0 / torch.sqrt(h.real ** 2 + h.imag ** 2 + EPSILON ** 2)
    out = torch.stack([h.real * inv, h.imag * inv], dim=-1)  # (b*c, bins, T, 2)
    out = out.reshape(b, c, NUM_BINS, t_len, 2).permute(0, 3, 1, 2, 4).reshape(b, t_len, c * NUM_BINS * 2)
    out = out.to(dtype)
    return out[0] if squeeze else out
