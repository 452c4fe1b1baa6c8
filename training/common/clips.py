"""The training clips: paired dances (motion and music) for the pose VQ-VAEs and the sequence model, built
from the data engineer's motion cache (training.data.prepare) and the engine's feature extractor
(training.features.extract), with tempo augmentation and the engine's tempo-normalised timeline. Also the
split (training/split.json) and the style rows of a run.

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

from training.data import prepare
from training.data import representation as rep
from training.data.aistpp import AIST_GENRES
from training.data.skeleton import mirror_positions
from training.eval.music import stretch_audio
from training.eval.tempo import dominant_period, time_stretch_motion
from training.features.extract import extract_clock, extract_features

REPO = pathlib.Path(__file__).resolve().parents[2]
MOTION_CACHE = REPO / "training" / "cache" / "motion"
STRETCH_CACHE = REPO / "training" / "cache" / "stretched_audio"
BAR_PHASE_COS = 105  # feature index of bar_phase (cos, sin): docs/features.md
TEMPOGRAM, TEMPO = 54, 104  # feature indices of the tempogram (48 entries) and the running tempo
FEATURE_CACHE = REPO / "training" / "cache" / "features"
# The style rows of a model trained on the data at hand (Tang, CMU salsa, Perfume): the shipped layout.
STYLES = ["cha-cha", "rumba", "tango", "waltz", "salsa", "pop"]
# AIST++'s genres (training.data.aistpp.AIST_GENRES) not among STYLES: rows 6.. of a model trained with AIST++
# dances converted (training.data.prepare --aistpp). A run's rows are styles_for(its songs).
EXTRA_STYLES = [g for g in AIST_GENRES.values() if g not in STYLES]
ALL_STYLES = STYLES + EXTRA_STYLES
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


def style_index(name: str) -> int:
  """A style label's row (ALL_STYLES), or ValueError naming the known labels."""
  if name not in ALL_STYLES:
    raise ValueError(f"unknown style label '{name}' (known: {', '.join(ALL_STYLES)})")
  return ALL_STYLES.index(name)


def styles_for(ids: list[str]) -> list[str]:
  """The style rows of a model trained on the motions `ids`: STYLES when every label is one of them (the
  shipped layout), else ALL_STYLES (AIST++'s genres appended, so a style's row does not depend on which
  genres a user converted)."""
  labels = {str(np.load(MOTION_CACHE / f"{i}.npz")["style"]) for i in ids}
  for name in labels:
    style_index(name)
  return list(STYLES) if labels <= set(STYLES) else list(ALL_STYLES)


def run_styles(split: dict) -> list[str]:
  """The style rows of a model trained on `split`'s paired dances (training and validation): styles_for."""
  return styles_for(paired_ids(split["train"] + split["validation"]))


def load_split() -> dict:
  with open(REPO / "training" / "split.json") as f:
    return json.load(f)


def ensure_motion_cache() -> None:
  """Runs the data engineer's preparation if the motion cache is missing."""
  if not MOTION_CACHE.is_dir() or not any(MOTION_CACHE.glob("*.npz")):
    prepare.main([])


def music_for(audio_path: str, factor: float) -> dict:
  """Features and PRE of the song played `factor` times faster (cached)."""
  return extract_features(stretched_audio(audio_path, factor), cache_dir=FEATURE_CACHE)


def load_clip(motion_id: str, factor: float = 1.0, with_music: bool = True, mirror: bool = False) -> Clip:
  """mirror: the dance reflected left-right (skeleton.mirror_positions), on the same music."""
  z = np.load(MOTION_CACHE / f"{motion_id}.npz")
  pos = z["positions"].astype(np.float64)
  if mirror:
    pos = mirror_positions(pos)
  if abs(factor - 1.0) > 1e-6:
    pos = time_stretch_motion(pos, factor)
  upper, lower = rep.encode(pos)
  style = style_index(str(z["style"]))
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


def style_reference_tempi(ids: list[str], default_bpm: float, styles: list[str] | None = None) -> dict[str, float]:
  """Each style's typical tempo on the engine's tracker, from the paired songs in `ids`: the circular mean
  of log2(song tempo) modulo 1 (the song tempo is the tracker's median running tempo, whatever octave it
  locked to), in the octave [75, 150). The styles are `styles` (a run's rows, styles_for; default: STYLES and
  the other styles with songs in `ids`); those without paired songs get `default_bpm`. Every song of a style
  is then warped with the same reference, so its octave folds the same way at any tempo near the typical
  one (docs/model.md section 1)."""
  by_style: dict[str, list[float]] = {}
  for mid in ids:
    z = np.load(MOTION_CACHE / f"{mid}.npz")
    if not str(z["audio_path"]):
      continue
    tempo = extract_features(str(z["audio_path"]), cache_dir=FEATURE_CACHE)["summary"]["tempo_median_bpm"]
    by_style.setdefault(str(z["style"]), []).append(float(tempo))
  refs = {}
  for style in styles if styles is not None else [s for s in ALL_STYLES if s in STYLES or s in by_style]:
    t = by_style.get(style)
    if not t:
      refs[style] = float(default_bpm)
      continue
    phase = np.angle(np.exp(2j * np.pi * (np.log2(t) % 1.0)).mean()) / (2 * np.pi) % 1.0
    r = 2.0 ** (6.0 + phase)  # in [64, 128)
    refs[style] = float(round(r * 2.0 if r < 75.0 else r, 2))
  return refs


# The bar clock of tempo-normalised models (docs/model.md section 1; training.train --bar-clock): beats per bar
# by style; the export writes it into the model's time_base, the engine's session applies it.
BAR_CLOCK = {"beats_per_bar": 4, "style_beats_per_bar": {"waltz": 3}}


def bar_beats_of(style: str, bar_clock: dict | None) -> int:
  if not bar_clock:
    return 0
  return int(bar_clock.get("style_beats_per_bar", {}).get(style, bar_clock["beats_per_bar"]))


def stretched_audio(audio_path: str, factor: float) -> str:
  """The song played `factor` times faster (sox tempo, pitch kept; cached): its own path at factor 1."""
  if abs(factor - 1.0) < 1e-6:
    return audio_path
  src = pathlib.Path(audio_path)
  dst = STRETCH_CACHE / f"{src.parent.name}_{src.stem}_x{factor:.3f}.wav"
  if not dst.is_file():
    stretch_audio(src, factor, dst)
  return str(dst)


def load_warped_clip(motion_id: str, reference_bpm: float, frames_per_step: int = 4, bar_beats: int = 0,
                     mirror: bool = False, factor: float = 1.0, fold_tempo: bool = False) -> Clip:
  """A paired dance on the tempo-normalised timeline of the engine's TempoClock (docs/model.md section 8):
  warped frame j takes the features and PRE of its source frame and the motion at its real position
  (linear interpolation of joint positions), so every song plays at `reference_bpm`. The clip starts at
  the first step boundary (a multiple of frames_per_step on the song's warped timeline, as the engine's
  steps) at or after the dance's first frame and ends where the dance or the music ends. bar_beats > 0: the
  `bar_phase` features are the bar clock's (the engine's audio::BarClockPhase of warped frame j, from
  `dance-features --clock --bar-beats`), as a session of a model with a bar clock sees them. mirror: the
  dance reflected left-right (skeleton.mirror_positions). factor != 1: the music is the song played
  `factor` times faster (tempo augmentation of the warped timeline): the clock folds it to the same
  reference tempo, so the warped dance is (up to the tracker) the same, while the features carry the other
  tempo (the running tempo, the tempogram, PRE's real-time phases), and the model learns that a style's
  dance in beat time does not depend on the song's absolute tempo. fold_tempo: the `tempogram` and `tempo`
  features are shown folded to the reference tempo (the engine's audio::FoldTempoFeatures with the source
  frame's clock rate, from `dance-features --clock --fold-tempo`), as a session of a model with
  time_base.fold_tempo sees them: every song of a style then plays at one tempo in the features too."""
  z = np.load(MOTION_CACHE / f"{motion_id}.npz")
  pos = z["positions"].astype(np.float64)
  if mirror:
    pos = mirror_positions(pos)
  song = str(z["audio_path"])
  if not pathlib.Path(song).is_absolute():
    song = str((REPO / song).resolve())
  audio = stretched_audio(song, factor)
  m = extract_features(audio, cache_dir=FEATURE_CACHE)
  clock = extract_clock(audio, reference_bpm, cache_dir=FEATURE_CACHE, bar_beats=bar_beats,
                        fold_tempo=fold_tempo).astype(np.float64)
  n0 = int(round(float(z["audio_offset_s"]) / factor * 30))
  # x: position in the dance's own (unstretched) frames; the stretched audio's frame k is the song's k * factor
  src, x = clock[:, 0].astype(np.int64), (clock[:, 1] - n0) * factor
  ok = np.flatnonzero((x >= 0) & (x <= len(pos) - 1) & (src < len(m["features"])))
  if len(ok) < 2 * frames_per_step:
    raise ValueError(f"{motion_id}: too short on the warped timeline")
  j0 = int(-(-ok[0] // frames_per_step) * frames_per_step)
  sel = np.arange(j0, ok[-1] + 1)
  xs = x[sel]
  i = np.minimum(np.floor(xs).astype(np.int64), len(pos) - 2)
  w = (xs - i)[:, None, None]
  warped = pos[i] * (1 - w) + pos[i + 1] * w
  upper, lower = rep.encode(warped)
  clip = Clip(motion_id, factor, style_index(str(z["style"])), upper.astype(np.float32),
              lower.astype(np.float32), warped.astype(np.float32))
  clip.features = m["features"][src[sel]].astype(np.float32)
  if bar_beats > 0:
    clip.features[:, BAR_PHASE_COS:BAR_PHASE_COS + 2] = clock[sel, 2:4].astype(np.float32)
  if fold_tempo:
    c0 = 4 if bar_beats > 0 else 2
    clip.features[:, TEMPOGRAM:TEMPOGRAM + 48] = clock[sel, c0:c0 + 48].astype(np.float32)
    clip.features[:, TEMPO] = clock[sel, c0 + 48].astype(np.float32)
  clip.pre = m["pre"][src[sel]].astype(np.float32)
  clip.audio_path, clip.audio_offset_s = audio, float(z["audio_offset_s"]) / factor
  return clip


def dance_period_beats(ids: list[str], refs: dict[str, float]) -> dict[str, int]:
  """Each style's dance period in beats, measured on the paired dances in `ids` on the tempo-normalised
  timeline: the dominant period of the warped motion (training.eval.tempo.dominant_period) over the
  style's beat at its reference tempo (1800 / R warped frames), the median over the style's songs, rounded
  to whole beats (1..16, the engine's range). Styles without paired dances are left out (no period: the
  engine's period lock is off for them). The export writes it into the model's time_base (`dance_period_beats`)."""
  by_style: dict[str, list[float]] = {}
  for mid in ids:
    z = np.load(MOTION_CACHE / f"{mid}.npz")
    style = str(z["style"])
    if not str(z["audio_path"]) or style not in refs:
      continue
    period_frames = dominant_period(load_warped_clip(mid, refs[style]).positions) * 30.0
    if np.isfinite(period_frames):
      by_style.setdefault(style, []).append(period_frames / (1800.0 / refs[style]))
  return {style: min(16, max(1, int(round(float(np.median(b)))))) for style, b in sorted(by_style.items())}


def tang_ids(ids: list[str]) -> list[str]:
  """The Tang songs among `ids`: the ones the evaluation (training/eval) scores."""
  return [i for i in ids if i.startswith("tang_")]


def paired_ids(ids: list[str]) -> list[str]:
  """The dances among `ids` that have music: the Tang songs, and any other converted dance whose motion
  cache names its audio (AIST++ after training.data.prepare --aistpp). Salsa and Perfume have none."""
  def has_music(i: str) -> bool:
    if i.startswith("tang_"):
      return True
    p = MOTION_CACHE / f"{i}.npz"
    return p.is_file() and bool(str(np.load(p)["audio_path"]))
  return [i for i in ids if has_music(i)]
