"""Training windows for SGMD: the paired dances (and their mirror images) cut into 5-s windows, each in its
own canonical frame (training.diffusion.motion), with the engine's music features of the same frames.

    data = WindowData.load(ids, mirror=True)
    stats = data.stats(rng)                       # pose and music normalisation (exported with the model)
    x0, music, style = data.batch(rng, 32, stats)  # normalised (B, N, 78), (B, N/2, 2 (F+P)), (B,)
"""
from __future__ import annotations

import dataclasses

import numpy as np

from training.common import clips as td
from training.diffusion import motion


@dataclasses.dataclass
class Stats:
  pose_mean: np.ndarray     # (78,)
  pose_std: np.ndarray
  music_mean: np.ndarray    # (F,)
  music_std: np.ndarray


@dataclasses.dataclass
class Song:
  motion_id: str
  style: int
  positions: np.ndarray     # (T, 24, 3) world
  features: np.ndarray      # (T, F)
  pre: np.ndarray           # (T, P)


def window_vector(positions: np.ndarray) -> np.ndarray:
  """World positions of one window -> its motion vectors in the window's canonical frame."""
  yaw, origin = motion.frame_of(positions[0])
  return motion.motion_vector(motion.positions_in_frame(positions, yaw, origin))


def music_tokens(features: np.ndarray, pre: np.ndarray, stats: Stats, frames_per_token: int) -> np.ndarray:
  """(N, F), (N, P) -> (N / k, k (F + P)): per frame [(f - mean) / std, pre], k frames per token."""
  f = (features - stats.music_mean) / stats.music_std
  rows = np.concatenate([f, pre], axis=-1)
  n = len(rows) // frames_per_token
  return rows[:n * frames_per_token].reshape(n, -1)


class WindowData:
  def __init__(self, songs: list[Song], frames: int, frames_per_token: int, style_balance: float = 0.5):
    self.songs = [s for s in songs if len(s.positions) >= frames]
    if not self.songs:
      raise ValueError(f"no dance has {frames} frames")
    self.frames, self.k = frames, frames_per_token
    lengths = np.array([len(s.positions) - frames + 1 for s in self.songs], dtype=np.float64)
    per_style = {}
    for s, n in zip(self.songs, lengths):
      per_style[s.style] = per_style.get(s.style, 0.0) + n
    w = lengths * np.array([per_style[s.style] ** -style_balance for s in self.songs])
    self.probs = w / w.sum()

  @classmethod
  def load(cls, ids: list[str], frames: int, frames_per_token: int, mirror: bool = True,
           style_balance: float = 0.5) -> "WindowData":
    songs = []
    for mid in ids:
      for m in ([False, True] if mirror else [False]):
        c = td.load_clip(mid, 1.0, with_music=True, mirror=m)
        if c.features is None:
          continue
        songs.append(Song(mid + ("~m" if m else ""), c.style, c.positions.astype(np.float64), c.features, c.pre))
    return cls(songs, frames, frames_per_token, style_balance)

  def window(self, rng: np.random.Generator) -> tuple[Song, int]:
    s = self.songs[rng.choice(len(self.songs), p=self.probs)]
    return s, int(rng.integers(0, len(s.positions) - self.frames + 1))

  def stats(self, rng: np.random.Generator, n: int = 1500) -> Stats:
    vs = np.stack([window_vector(s.positions[a:a + self.frames]) for s, a in (self.window(rng) for _ in range(n))])
    feats = np.concatenate([s.features for s in self.songs])
    return Stats(vs.reshape(-1, motion.POSE_DIM).mean(0), np.maximum(vs.reshape(-1, motion.POSE_DIM).std(0), 1e-3),
                 feats.mean(0), np.maximum(feats.std(0), 1e-3))

  def batch(self, rng: np.random.Generator, size: int, stats: Stats):
    xs, ms, st = [], [], []
    for _ in range(size):
      s, a = self.window(rng)
      xs.append((window_vector(s.positions[a:a + self.frames]) - stats.pose_mean) / stats.pose_std)
      ms.append(music_tokens(s.features[a:a + self.frames], s.pre[a:a + self.frames], stats, self.k))
      st.append(s.style)
    return np.stack(xs).astype(np.float32), np.stack(ms).astype(np.float32), np.array(st)
