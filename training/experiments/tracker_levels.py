"""Does the engine's beat tracker keep its metrical level when the music is played faster or slower?

For each paired Tang song: the first `--seconds` (sox trim), and that excerpt stretched to 0.85x and 1.15x
(sox tempo, pitch kept); the engine's running tempo (`dance-features`, feature `tempo`) per 10-s window of
music time (window k of a version played f times as fast covers real seconds [10k / f, 10(k+1) / f)).
A window is *off-level* when the stretched version's median tempo, divided by f, is not the original's up
to whole octaves (|log2 error mod 1| > 0.05, about 3.5 %): the tempo clock folds octaves, so only other
ratios (3/2, 4/3) make it lose the tempo. Octave flips (a window's tempo about 2x or 1/2 its
predecessor's) do not move the clock but change the beat and bar phase features. An *octave mismatch* is a
window where the stretched version sits on another octave than the original (unfolded |log2 error| > 0.5):
the clock agrees, the beat and bar phases of the two versions do not, so a dance cannot scale with the
music there. The first window (lock-in) is not scored.

  /usr/bin/python3 -m training.experiments.tracker_levels [--songs all|train|validation|ID,...] [--out r.json]

Needs `dance-features` (DANCE_BUILD_DIR, default build/) and sox.
"""
from __future__ import annotations

import argparse
import json
import pathlib
import tempfile

import numpy as np

from training import tools
from training.common import clips as td
from training.eval.engine_tempo import song_excerpt
from training.eval.music import stretch_audio

FACTORS = (0.85, 1.15)
WINDOW_S = 10.0


def window_tempi(tempo: np.ndarray, factor: float, windows: int) -> list[float]:
  """Median running tempo (BPM) per WINDOW_S window of music time of a version played `factor` x as fast."""
  out = []
  for k in range(windows):
    a, b = int(k * WINDOW_S / factor * 30), int((k + 1) * WINDOW_S / factor * 30)
    out.append(float(np.median(tempo[a:b])) if b <= len(tempo) and b > a else float("nan"))
  return out


def level_errors(base: list[float], stretched: list[float], factor: float) -> list[float]:
  """Per window (from the second on): log2 of stretched / (factor x base), folded into [-0.5, 0.5)."""
  e = np.log2(np.asarray(stretched[1:]) / np.asarray(base[1:]) / factor)
  return list((e + 0.5) % 1.0 - 0.5)


def octave_mismatches(base: list[float], stretched: list[float], factor: float) -> int:
  """Windows (from the second on) where stretched / (factor x base) is nearer another octave than 1."""
  e = np.log2(np.asarray(stretched[1:]) / np.asarray(base[1:]) / factor)
  return int(np.sum(np.abs(e) > 0.5))


def octave_flips(tempi: list[float]) -> int:
  t = np.asarray(tempi[1:])
  return int(np.sum(np.abs(np.log2(t[1:] / t[:-1])) > 0.7))


def main(argv=None) -> None:
  ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  ap.add_argument("--songs", default="all", help="all, train, validation, or comma-separated motion ids")
  ap.add_argument("--seconds", type=float, default=60.0)
  ap.add_argument("--out", default=None)
  args = ap.parse_args(argv)
  split = td.load_split()
  if args.songs == "all":
    ids = td.tang_ids(split["train"]) + td.tang_ids(split["validation"])
  elif args.songs in ("train", "validation"):
    ids = td.tang_ids(split[args.songs])
  else:
    ids = args.songs.split(",")
  windows = int(args.seconds // WINDOW_S)
  cli = tools.require("dance-features")
  rows = []
  with tempfile.TemporaryDirectory() as tmp:
    work = pathlib.Path(tmp)
    for mid in ids:
      z = np.load(td.MOTION_CACHE / f"{mid}.npz")
      excerpt = pathlib.Path(song_excerpt(str(z["audio_path"]), args.seconds, work / f"{mid}.wav"))
      tempi = {}
      for f in (1.0,) + FACTORS:
        wav = excerpt if f == 1.0 else stretch_audio(excerpt, f, work / f"{mid}_x{f}.wav")
        npy = work / f"{mid}_x{f}.npy"
        tools.dance_features(wav, out=npy, cli=cli)
        tempi[f] = window_tempi(120.0 * 2.0 ** np.load(npy)[:, 104].astype(np.float64), f, windows)
      errs = [e for f in FACTORS for e in level_errors(tempi[1.0], tempi[f], f)]
      off = int(np.sum(np.abs(errs) > 0.05))
      flips = sum(octave_flips(t) for t in tempi.values())
      mism = sum(octave_mismatches(tempi[1.0], tempi[f], f) for f in FACTORS)
      rows.append({"id": mid, "style": str(z["style"]), "tempi": {str(f): t for f, t in tempi.items()},
                   "off_level": off, "windows": len(errs), "octave_flips": flips, "octave_mismatches": mism})
      print(f"{mid:18s} {str(z['style']):8s} off-level {off}/{len(errs)}  octave flips {flips}  "
            f"mismatches {mism}  " +
            " | ".join(f"{f}x: " + " ".join(f"{t:4.0f}" for t in tempi[f]) for f in (1.0,) + FACTORS), flush=True)
  off = sum(r["off_level"] for r in rows)
  n = sum(r["windows"] for r in rows)
  flips = sum(r["octave_flips"] for r in rows)
  mism = sum(r["octave_mismatches"] for r in rows)
  print(f"off-level windows {off}/{n}; octave flips {flips}; octave mismatches stretched vs original {mism}/{n} "
        f"({len(rows)} songs)")
  if args.out:
    pathlib.Path(args.out).write_text(json.dumps({"off_level": off, "windows": n, "octave_flips": flips,
                                                  "octave_mismatches": mism, "rows": rows}, indent=1))


if __name__ == "__main__":
  main()
