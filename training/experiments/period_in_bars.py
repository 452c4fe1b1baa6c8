"""The dominant period of the generated dances in bars of their music, beside the real dancer's.

Reads `training.eval.engine_tempo` reports (the base period of every run on the original music) and a
`training.experiments.tracker_levels` report (the song's tracked tempo, windows 2-6 of the original), folds the
tempo into the style's reference octave as the tempo clock does, and prints, per validation song, the bar
length (waltz 3 beats, the others 4), the real dance's dominant period in bars (first 60 s) and every run's.
A dance locked to the music's bar would sit at one value (1 bar for the waltzes here, 1/2 bar for cha-cha
and rumba) in every run.

  /usr/bin/python3 -m training.experiments.period_in_bars --tempo A.json [B.json ...] --levels LEVELS.json \\
      --refs RUN/style_reference_bpm.json
"""
from __future__ import annotations

import argparse
import json

import numpy as np

from training.common import clips as td
from training.eval.tempo import dominant_period

def bar_seconds(tempo_bpm: float, reference_bpm: float, style: str) -> float:
  """One bar at `tempo_bpm` folded by octaves to within sqrt 2 of the style's reference tempo."""
  folded = tempo_bpm * 2.0 ** np.round(np.log2(reference_bpm / tempo_bpm))
  return td.bar_beats_of(style, td.BAR_CLOCK) * 60.0 / folded  # the bar clock's metre: waltz 3, others 4


def main(argv=None) -> None:
  ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  ap.add_argument("--tempo", nargs="+", required=True, help="engine_tempo JSON reports")
  ap.add_argument("--levels", required=True, help="tracker_levels JSON report")
  ap.add_argument("--refs", required=True, help="style_reference_bpm.json of the model's run")
  args = ap.parse_args(argv)
  levels = {r["id"]: r for r in json.load(open(args.levels))["rows"]}
  refs = json.load(open(args.refs))
  runs: dict[str, list[float]] = {}
  for path in args.tempo:
    for r in json.load(open(path))["rows"]:
      if r.get("base_period_s"):
        runs.setdefault(r["id"], []).append(float(r["base_period_s"]))
  for mid, periods in runs.items():
    z = np.load(td.MOTION_CACHE / f"{mid}.npz")
    style = str(z["style"])
    bar = bar_seconds(float(np.median(levels[mid]["tempi"]["1.0"][1:])), refs[style], style)
    real = dominant_period(z["positions"][:60 * 30])
    print(f"{mid:17s} {style:8s} bar {bar:.2f} s  real {real / bar:.2f} bars  runs ({len(periods)}): " +
          " ".join(f"{p / bar:.2f}" for p in sorted(periods)))


if __name__ == "__main__":
  main()
