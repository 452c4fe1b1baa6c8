"""Music side of the evaluation: beats and tempo, and time-stretching.

Two beat sources:
- "librosa": offline beat tracking (librosa.beat.beat_track, whole song, non-causal), the reference for
  evaluation because it is what the literature's BAS uses and it has no start-up or octave trouble on
  these songs. librosa lives only in /work/main/.venv (reports and tests), so its results are cached as
  JSON in training/cache/beats/ (`.venv/bin/python -m training.eval.music AUDIO...` fills the cache);
  Debian's python3 then reads the cache.
- "engine": `dance-features --summary` (the engine's causal tracker, via training/features/extract.py).
  On this data it often locks to double or 1.5x the tempo (docs/data.md), so it is a fallback only.
source="auto" uses the librosa cache when present, else librosa if importable, else the engine.
Stretching uses `sox tempo` (keeps pitch).

Usage:
  info = music_info("song.ogg")               # {"tempo_bpm", "beats_s", "duration_s", "source"}
  stretch_audio("song.ogg", 1.15, "fast.wav")  # 15 % faster, same pitch
"""
from __future__ import annotations

import functools
import hashlib
import json
import pathlib
import subprocess
import sys

import numpy as np

from training.features.extract import extract_features

BEAT_CACHE = pathlib.Path(__file__).resolve().parents[1] / "cache" / "beats"


def _key(audio_path: str) -> str:
  h = hashlib.sha256()
  with open(audio_path, "rb") as f:
    for block in iter(lambda: f.read(1 << 20), b""):
      h.update(block)
  return h.hexdigest()[:16]


# Dance-sport tempo ranges (beats per minute): a tracker's estimate outside its style's range is folded
# by x2, /2, x2/3 or x3/2 (the first that fits; 3/4 time makes trackers lock to 1.5x) into it, and the
# beats are tracked again at that tempo. Songs without a style are left as tracked.
STYLE_TEMPO_RANGE = {"waltz": (75.0, 100.0), "rumba": (80.0, 115.0), "cha-cha": (105.0, 135.0),
                     "tango": (110.0, 140.0)}


def librosa_info(audio_path: str, style: str | None = None) -> dict:
  import librosa  # only in .venv
  y, sr = librosa.load(audio_path, sr=22050, mono=True)
  onset = librosa.onset.onset_strength(y=y, sr=sr)
  tempo, beats = librosa.beat.beat_track(onset_envelope=onset, sr=sr, units="time")
  tempo = float(np.atleast_1d(tempo)[0])
  raw = tempo
  lo, hi = STYLE_TEMPO_RANGE.get(style or "", (0.0, np.inf))
  for f in (2.0, 0.5, 2.0 / 3.0, 1.5):
    if lo <= tempo <= hi:
      break
    if lo <= raw * f <= hi:
      tempo = raw * f
  if tempo != raw:
    _, beats = librosa.beat.beat_track(onset_envelope=onset, sr=sr, units="time", bpm=tempo)
  return {"tempo_bpm": tempo, "tracked_tempo_bpm": raw, "beats_s": [float(b) for b in beats],
          "duration_s": float(len(y) / sr), "source": "librosa", "style_prior": style or ""}


def warm_librosa() -> bool:
  """Runs librosa's beat tracker, both ways librosa_info calls it, on four seconds of clicks in this process,
  so that its numba cache (cache=True, under .venv's site-packages) is compiled and written by one process.
  Processes that compile it at the same time can write an inconsistent cache, and every later beat track
  in that .venv then segfaults (numba issue #10128; seen here 2026-12-06 after parallel engine_suite lanes:
  `find .venv -name '*.nb[ci]' -delete` repairs it). Call it before starting parallel workers that track
  beats. False when librosa is not importable (Debian's python3)."""
  try:
    import librosa  # only in .venv
  except ImportError:
    return False
  sr = 22050
  y = np.zeros(4 * sr, np.float32)
  y[::sr // 2] = 1.0  # clicks at 120 BPM
  onset = librosa.onset.onset_strength(y=y, sr=sr)
  librosa.beat.beat_track(onset_envelope=onset, sr=sr, units="time")
  librosa.beat.beat_track(onset_envelope=onset, sr=sr, units="time", bpm=120.0)
  return True


def engine_info(audio_path: str) -> dict:
  s = extract_features(audio_path)["summary"]
  return {"tempo_bpm": float(s["tempo_bpm"]), "beats_s": list(s["beats_s"]),
          "duration_s": float(s["duration_s"]), "source": "engine"}


@functools.lru_cache(maxsize=256)
def music_info(audio_path: str, source: str = "auto") -> dict:
  """Tempo (BPM), beat times (s, song time), duration and the beat source of an audio file."""
  audio_path = str(audio_path)
  if source == "engine":
    info = engine_info(audio_path)
  else:
    cache = BEAT_CACHE / f"{_key(audio_path)}.json"
    if cache.exists():
      info = json.loads(cache.read_text())
    else:
      try:
        info = librosa_info(audio_path)
        cache.parent.mkdir(parents=True, exist_ok=True)
        cache.write_text(json.dumps(info))
      except ImportError:
        if source == "librosa":
          raise
        print(f"warning: no cached librosa beats for {audio_path}; using the engine's beat tracker "
              "(fill the cache with `.venv/bin/python -m training.eval.music`)", file=sys.stderr)
        info = engine_info(audio_path)
  return dict(info, beats_s=np.asarray(info["beats_s"], dtype=np.float64))


def beats_for_dance(audio_path: str, audio_offset_s: float) -> np.ndarray:
  """Music beats re-expressed on the dance's timeline (frame 0 at t = 0)."""
  return music_info(str(audio_path))["beats_s"] - audio_offset_s


def beat_period_s(beats_s: np.ndarray, start_s: float = -np.inf, end_s: float = np.inf) -> float:
  """Median inter-beat interval of the beats inside [start, end)."""
  b = beats_s[(beats_s >= start_s) & (beats_s < end_s)]
  return float(np.median(np.diff(b))) if len(b) > 2 else float("nan")


def stretch_audio(src: str | pathlib.Path, factor: float, dst: str | pathlib.Path) -> pathlib.Path:
  """Writes `src` played `factor` times faster with the pitch kept (sox tempo), as 24 kHz mono float WAV
  (deterministic: the same input gives the same bytes)."""
  dst = pathlib.Path(dst)
  dst.parent.mkdir(parents=True, exist_ok=True)
  # 32-bit float output: sox dithers (randomly) when it writes 16-bit, which made runs differ.
  cmd = ["sox", str(src), "-e", "floating-point", "-b", "32", "-r", "24000", "-c", "1", str(dst),
         "tempo", "-m", f"{factor:.6f}"]
  proc = subprocess.run(cmd, capture_output=True, text=True)
  if proc.returncode != 0:
    raise RuntimeError(f"sox failed ({' '.join(cmd)}): {proc.stderr.strip()}")
  return dst


def fill_cache(audio_path: str, style: str | None = None) -> dict:
  """Tracks beats with librosa (style-folded tempo) and writes the cache entry; .venv only."""
  info = librosa_info(str(audio_path), style)
  BEAT_CACHE.mkdir(parents=True, exist_ok=True)
  (BEAT_CACHE / f"{_key(str(audio_path))}.json").write_text(json.dumps(info))
  music_info.cache_clear()
  return info


if __name__ == "__main__":
  # .venv/bin/python -m training.eval.music [--style STYLE] AUDIO...   (default: every Tang song)
  args = sys.argv[1:]
  style = None
  if args[:1] == ["--style"]:
    style, args = args[1], args[2:]
  if args:
    todo = [(a, style) for a in args]
  else:
    from training.data.skeleton import SHARED_DATA
    from training.data.sources import TANG_STYLES
    todo = [(str(d / "audio.ogg"), TANG_STYLES[d.name.split("_")[1]])
            for d in sorted((SHARED_DATA / "tang2018").glob("DANCE_*"))]
  for a, st in todo:
    i = fill_cache(a, st)
    print(f"{a}: {i['tempo_bpm']:.1f} BPM (tracked {i['tracked_tempo_bpm']:.1f}), {len(i['beats_s'])} beats")
