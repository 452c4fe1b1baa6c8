"""Checks of the paired Tang data itself: music-dance alignment, motion periodicity against the tempo.

Run (after `python3 -m training.data.prepare` and the beat cache `.venv/bin/python -m training.eval.music`):
  /usr/bin/python3 -m training.eval.data_checks [--out training/cache/data_checks.json] [--plots DIR]
Prints a markdown table (docs/data.md keeps the findings).

Per dance:
- duration check: motion frames against the config's end - start (both 25 fps);
- tempo: librosa beats folded into the style's range (training/eval/music.py);
- dominant motion period (autocorrelation of mean joint speed, 0.3-4 s) and that period in beats;
- beat locking: motion beats (speed minima) as phases of the music's beat grid; R = |mean exp(i 2 pi phi)|
  (0 = no relation, 1 = every motion beat at the same beat phase), its chance level ~ sqrt(pi/4/N), the
  mean phase, and the drift of the phase over the dance (beats per minute; a wrong fps or a stretched
  recording would show as a steady drift);
- BAS against the beats and against randomly shifted beats (chance).
"""
from __future__ import annotations

import argparse
import json
import pathlib

import numpy as np

from training.data import prepare
from training.eval import metrics, music, tempo


def beat_phases(events_s: np.ndarray, beats_s: np.ndarray) -> np.ndarray:
  """Phase in [0, 1) of each event within the beat interval that contains it (events outside dropped)."""
  i = np.searchsorted(beats_s, events_s, side="right") - 1
  ok = (i >= 0) & (i < len(beats_s) - 1)
  i, e = i[ok], events_s[ok]
  return (e - beats_s[i]) / (beats_s[i + 1] - beats_s[i])


def phase_drift(events_s: np.ndarray, beats_s: np.ndarray, window_s: float = 20.0) -> float:
  """Slope (beats/minute) of the circular-mean phase over sliding windows."""
  if len(events_s) == 0:
    return float("nan")
  starts = np.arange(events_s.min(), events_s.max() - window_s, window_s / 2)
  angles, times = [], []
  for s in starts:
    ph = beat_phases(events_s[(events_s >= s) & (events_s < s + window_s)], beats_s)
    if len(ph) >= 8:
      angles.append(np.angle(np.exp(2j * np.pi * ph).mean()))
      times.append(s + window_s / 2)
  if len(angles) < 3:
    return float("nan")
  un = np.unwrap(np.array(angles)) / (2 * np.pi)
  return float(np.polyfit(np.array(times) / 60.0, un, 1)[0])


def check_dance(motion_id: str) -> dict:
  m = prepare.load_motion(motion_id)
  pos = m["positions"].astype(np.float64)
  notes = json.loads(m["notes"])
  cfg = notes.get("config", {})
  info = music.music_info(m["audio_path"])
  beats = info["beats_s"] - m["audio_offset_s"]
  dur = len(pos) / m["fps"]
  beats = beats[(beats >= 0) & (beats < dur)]
  ibi = music.beat_period_s(beats)
  period = tempo.dominant_period(pos, m["fps"])
  mb = metrics.motion_beats(pos, m["fps"])
  ph = beat_phases(mb, beats)
  z = np.exp(2j * np.pi * ph).mean() if len(ph) else 0.0
  return {
      "id": motion_id, "style": m["style"], "seconds": round(dur, 1),
      "frames_vs_config": (notes.get("source_frames", 0) - (cfg.get("end_position", 0) -
                                                            cfg.get("start_position", 0)))
      if cfg else None,
      "offset_s": m["audio_offset_s"], "tempo_bpm": round(info["tempo_bpm"], 1),
      "tracked_bpm": round(info.get("tracked_tempo_bpm", info["tempo_bpm"]), 1),
      "period_s": round(period, 3), "period_beats": round(period / ibi, 2),
      "period_strength": round(tempo.period_strength(pos, period, m["fps"]), 2),
      "lock_R": round(float(abs(z)), 3), "lock_chance": round(float(np.sqrt(np.pi / 4 / max(len(ph), 1))), 3),
      "lock_phase": round(float(np.angle(z) / (2 * np.pi)) % 1.0, 2),
      "phase_drift_beats_per_min": round(phase_drift(mb, beats), 3),
      "bas": round(metrics.beat_align_score(beats, mb), 3),
      "bas_chance": round(metrics.beat_align_chance(beats, mb), 3),
  }


def main(argv=None) -> int:
  ap = argparse.ArgumentParser()
  ap.add_argument("--out", type=pathlib.Path, default=prepare.REPO / "training/cache/data_checks.json")
  args = ap.parse_args(argv)
  ids = sorted(p.stem for p in prepare.CACHE.glob("tang_*.npz"))
  rows = [check_dance(i) for i in ids]
  args.out.write_text(json.dumps(rows, indent=1))
  cols = ["id", "style", "seconds", "frames_vs_config", "offset_s", "tempo_bpm", "tracked_bpm", "period_s",
          "period_beats", "period_strength", "lock_R", "lock_chance", "lock_phase",
          "phase_drift_beats_per_min", "bas", "bas_chance"]
  print("| " + " | ".join(cols) + " |")
  print("|" + "---|" * len(cols))
  for r in rows:
    print("| " + " | ".join(str(r[c]) for c in cols) + " |")
  for style in sorted({r["style"] for r in rows}):
    rs = [r for r in rows if r["style"] == style]
    print(f"{style}: n={len(rs)} period_beats median {np.median([r['period_beats'] for r in rs]):.2f}, "
          f"lock_R median {np.median([r['lock_R'] for r in rs]):.3f} (chance "
          f"{np.median([r['lock_chance'] for r in rs]):.3f}), BAS {np.mean([r['bas'] for r in rs]):.3f} vs "
          f"chance {np.mean([r['bas_chance'] for r in rs]):.3f}")
  return 0


if __name__ == "__main__":
  raise SystemExit(main())
