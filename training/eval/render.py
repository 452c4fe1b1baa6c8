"""Renderers: stick-figure frame strips and the beat-alignment plot, both to PNG (matplotlib, Agg).

Usage:
  render_strip(positions, "strip.png", fps=30, start_s=10, n=8, step_s=0.5, title="DANCE_W_3")
  render_beats(positions, music_beats_s, "beats.png", fps=30)
Left limbs are drawn in red, right limbs in blue, the trunk in black.
"""
from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from training.data import skeleton as sk  # noqa: E402


def _bone_colour(j: int) -> str:
  name = sk.JOINT_NAMES[j]
  return "tab:red" if name.startswith("left_") else "tab:blue" if name.startswith("right_") else "k"


def _facing_rotation(pose: np.ndarray) -> np.ndarray:
  """Rotation about Y that turns the pose to face +Z (the viewer looks at its front from +Z)."""
  across = pose[sk.J["left_hip"]] - pose[sk.J["right_hip"]] + pose[sk.J["left_shoulder"]] - \
      pose[sk.J["right_shoulder"]]
  fwd = np.cross(across, [0.0, 1.0, 0.0])
  yaw = np.arctan2(fwd[0], fwd[2])
  c, s = np.cos(-yaw), np.sin(-yaw)
  return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def render_strip(positions: np.ndarray, path: str, fps: float = 30.0, start_s: float = 0.0, n: int = 8,
                 step_s: float = 0.5, title: str = "", parents=None, views=("front", "top")) -> None:
  """Draws n frames from start_s every step_s: each frame seen from its own front (x-y, after turning it
  to face the viewer) and, in a second row, from above in world coordinates (x-z), with the floor."""
  parents = sk.load_skeleton().parents if parents is None else parents
  idx = [min(int(round((start_s + k * step_s) * fps)), len(positions) - 1) for k in range(n)]
  fig, axes = plt.subplots(len(views), n, figsize=(1.9 * n, 3.2 * len(views)), squeeze=False)
  for col, f in enumerate(idx):
    pose = positions[f].astype(np.float64)
    for row, view in enumerate(views):
      ax = axes[row, col]
      if view == "front":
        p = (pose - pose[0] * [1, 0, 1]) @ _facing_rotation(pose).T
        a, b = p[:, 0], p[:, 1]
        ax.axhline(0.0, color="0.6", lw=0.8)
        ax.set_xlim(-0.9, 0.9)
        ax.set_ylim(-0.05, 1.9)
      else:
        a, b = pose[:, 0], pose[:, 2]
        cx, cz = pose[0, 0], pose[0, 2]
        ax.set_xlim(cx - 0.8, cx + 0.8)
        ax.set_ylim(cz - 0.8, cz + 0.8)
      for j in range(1, len(parents)):
        ax.plot([a[j], a[parents[j]]], [b[j], b[parents[j]]], color=_bone_colour(j), lw=2)
      ax.plot(a[15], b[15], "o", color="k", ms=5)
      ax.set_aspect("equal")
      ax.set_xticks([])
      ax.set_yticks([])
      if row == 0:
        ax.set_title(f"{f / fps:.1f}s", fontsize=9)
    if col == 0:
      for row, view in enumerate(views):
        axes[row, 0].set_ylabel("front (own facing)" if view == "front" else "top (world x-z)",
                                fontsize=8)
  fig.suptitle(title + "  (red = left, blue = right)", fontsize=10)
  fig.tight_layout()
  fig.savefig(path, dpi=70)
  plt.close(fig)


def render_beats(speed: np.ndarray, motion_beats_s: np.ndarray, music_beats_s: np.ndarray, path: str,
                 fps: float = 30.0, window_s: tuple[float, float] | None = None, title: str = "") -> None:
  """Plots the kinetic speed curve with its motion beats (local minima) against the music beats."""
  t = np.arange(len(speed)) / fps
  lo, hi = window_s if window_s else (0.0, t[-1])
  m = (t >= lo) & (t <= hi)
  fig, ax = plt.subplots(figsize=(12, 3))
  ax.plot(t[m], speed[m], color="k", lw=1, label="mean joint speed (m/s)")
  for k, b in enumerate(music_beats_s[(music_beats_s >= lo) & (music_beats_s <= hi)]):
    ax.axvline(b, color="tab:orange", lw=1, alpha=0.8, label="music beat" if k == 0 else None)
  mb = motion_beats_s[(motion_beats_s >= lo) & (motion_beats_s <= hi)]
  ax.plot(mb, np.interp(mb, t, speed), "v", color="tab:blue", label="motion beat (speed minimum)")
  ax.set_xlabel("time in the dance (s)")
  ax.legend(loc="upper right", fontsize=8)
  ax.set_title(title, fontsize=10)
  fig.tight_layout()
  fig.savefig(path, dpi=70)
  plt.close(fig)
