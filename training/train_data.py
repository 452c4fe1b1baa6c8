"""Training data for the pose VQ-VAEs and the sequence model, built from the data engineer's motion cache
and the engine's feature extractor (training/features), with tempo augmentation.

Tempo augmentation: music and motion are time-stretched together. The audio with `sox tempo` (pitch kept)
before feature extraction (training.eval.music.stretch_audio; cached per factor), the motion by linear
resampling of joint positions (training.eval.tempo.time_stretch_motion) before re-encoding. A factor f > 1
plays f times faster; the dance's start in the song moves to audio_offset_s / f.

Alignment: pose frame n of a dance uses feature frame n0 + n, n0 = round(audio_offset_s * 30) (feature frame
n is the one computed from audio up to (n+1)/30 s of the song, docs/features.md).
"""
from __future__ import annotations

import dataclasses
import json
import pathlib

import numpy as np

from training.data import representation as rep
from training.eval.music import stretch_audio
from training.eval.tempo import time_stretch_motion
from training.features.extract import extract_features

REPO = pathlib.Path(__file__).resolve().parents[1]
MOTION_CACHE = REPO / "training" / "cache" / "motion"
STRETCH_CACHE = REPO / "training" / "cache" / "stretched_audio"
FEATURE_CACHE = REPO / "training" / "cache" / "features"
STYLES = ["cha-cha", "rumba", "tango", "waltz", "salsa", "pop"]
TEMPO_FACTORS = (0.8, 0.9, 1.0, 1.1, 1.25)


@dataclasses.dataclass
class Clip:
  """One dance (optionally time-stretched): per-frame pose features, and music if paired."""
  motion_id: str
  factor: float
  style: int
  upper: np.ndarray            # (T, 45) float32
  lower: np.ndarray            # (T, 31) float32
  positions: np.ndarray        # (T, 24, 3) float32
  features: np.ndarray | None = None  # (T, 108) aligned with the pose frames
  pre: np.ndarray | None = None       # (T, 128)
  audio_path: str | None = None
  audio_offset_s: float = 0.0


def load_split() -> dict:
  with open(REPO / "training" / "split.json") as f:
    return json.load(f)


def ensure_motion_cache() -> None:
  """Runs the data engineer's preparation if the motion cache is missing."""
  if not MOTION_CACHE.is_dir() or not any(MOTION_CACHE.glob("*.npz")):
    from training.data import prepare
    prepare.main([])


def music_for(audio_path: str, factor: float) -> dict:
  """Features and PRE of the song played `factor` times faster (cached)."""
  if abs(factor - 1.0) < 1e-6:
    return extract_features(audio_path, cache_dir=FEATURE_CACHE)
  src = pathlib.Path(audio_path)
  dst = STRETCH_CACHE / f"{src.parent.name}_{src.stem}_x{factor:.3f}.wav"
  if not dst.is_file():
    stretch_audio(src, factor, dst)
  return extract_features(dst, cache_dir=FEATURE_CACHE)


def load_clip(motion_id: str, factor: float = 1.0, with_music: bool = True) -> Clip:
  z = np.load(MOTION_CACHE / f"{motion_id}.npz")
  pos = z["positions"].astype(np.float64)
  if abs(factor - 1.0) > 1e-6:
    pos = time_stretch_motion(pos, factor)
  upper, lower = rep.encode(pos)
  style = STYLES.index(str(z["style"]))
  audio = str(z["audio_path"]) if "audio_path" in z.files and str(z["audio_path"]) else None
  clip = Clip(motion_id, factor, style, upper.astype(np.float32), lower.astype(np.float32),
              pos.astype(np.float32))
  if audio and not pathlib.Path(audio).is_absolute():
    audio = str((REPO / audio).resolve())
  if with_music and audio:
    offset = float(z["audio_offset_s"]) / factor
    m = music_for(audio, factor)
    n0 = int(round(offset * 30))
    feats, pre = m["features"][n0:], m["pre"][n0:]
    if n0 < 0:
      raise ValueError(f"{motion_id}: negative audio offset")
    t = min(len(feats), len(upper))
    clip.upper, clip.lower, clip.positions = clip.upper[:t], clip.lower[:t], clip.positions[:t]
    clip.features, clip.pre = feats[:t].astype(np.float32), pre[:t].astype(np.float32)
    clip.audio_path, clip.audio_offset_s = audio, offset
  return clip


def paired_ids(ids: list[str]) -> list[str]:
  return [i for i in ids if i.startswith("tang_")]
