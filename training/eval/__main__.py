"""Command line of the evaluation (docs/evaluation.md).

  python3 -m training.eval baselines [--json OUT]          real / wrong music / frozen table (markdown)
  python3 -m training.eval metrics FILE... [--name NAME] [--audio A --offset S] [--json OUT]
      FILE: dance-motion/v1 JSON (audio from its "audio_path" key or --audio) or prepare-cache npz.
      Prints the baselines and this set in one table.
  python3 -m training.eval tempo [--songs N] [--json OUT]  tempo-following ratio of the real baselines, and
      the per-run statistic for an ideal follower whose draws are sections of the real dances
  python3 -m training.eval render FILE --out PREFIX [--start S] [--audio A --offset S]
      writes PREFIX_strip.png (stick figures) and PREFIX_beats.png (music vs motion beats)
Run from the repository root with /usr/bin/python3 (beats come from training/cache/beats, filled by
`.venv/bin/python -m training.eval.music`).
"""
from __future__ import annotations

import argparse
import json
import pathlib
import sys
import tempfile

import numpy as np

from training.eval import evaluate, metrics, render, tempo


def _cmd_baselines(args) -> dict:
  ev = evaluate.Evaluator.default()
  rows = ev.baselines()
  if getattr(args, "files", None):
    dances = [evaluate.load_dance(f, args.audio, args.offset) for f in args.files]
    rows[args.name] = ev.evaluate(dances)
  print(evaluate.markdown_table(rows))
  if args.json:
    pathlib.Path(args.json).write_text(json.dumps(rows, indent=1))
  return rows


def _cmd_tempo(args) -> dict:
  """Tempo following of reference generators on the validation songs: the real dance time-stretched with
  the music (a perfect follower), the real dance unchanged (ignores the music), and its first half for the
  original song against its second half for the stretched ones (ignores the music; shows the noise)."""
  val = evaluate.cached_dances(evaluate.split_ids("validation"))[:args.songs]
  out = {}
  with tempfile.TemporaryDirectory() as tmp:
    for name, mode in (("real, stretched with the music", "follow"), ("real, unchanged", "same"),
                       ("real, other half (ignores music)", "halves")):
      ratios = []
      for d in val:
        def generate(audio_path, d=d, mode=mode):
          f = 1.0
          if "_x" in pathlib.Path(audio_path).stem:
            f = float(pathlib.Path(audio_path).stem.rsplit("_x", 1)[1])
          if mode == "follow":
            return tempo.time_stretch_motion(d.positions, f)
          if mode == "halves":   # the estimator's noise: a different stretch of the same dance
            h = len(d.positions) // 2
            return d.positions[:h] if f == 1.0 else d.positions[h:]
          return d.positions
        r = tempo.tempo_following(generate, d.audio_path, pathlib.Path(tmp) / d.name)
        ratios.append(r["ratio"])
        print(f"{name:32s} {d.name:20s} base period {r['base_period_s']:.3f} s, periods "
              f"{[round(p, 3) for p in r['periods_s']]}, ratio {r['ratio']:.3f}")
      out[name] = {"mean_ratio": float(np.nanmean(ratios)), "ratios": ratios}
      print(f"{name}: mean ratio {out[name]['mean_ratio']:.3f}")
  # What the per-run statistic gives a dancer-like ideal follower: sections of the real dances as draws
  # (all paired Tang dances: the validation ones alone have too few sections).
  ids = evaluate.split_ids("validation") + evaluate.split_ids("train")
  for window in (30.0, 60.0):
    by_style: dict[str, list[float]] = {}
    for d in evaluate.cached_dances(ids):
      by_style.setdefault(d.style, []).extend(tempo.section_follower_ratios(d.positions, window_s=window))
    name = f"real, {window:.0f} s sections as draws (ideal follower)"
    allr = [r for v in by_style.values() for r in v]
    out[name] = {"mean_ratio": float(np.mean(allr)) if allr else None,
                 "median_ratio": float(np.median(allr)) if allr else None, "runs": len(allr),
                 "by_style": {k: {"mean": float(np.mean(v)), "median": float(np.median(v)), "runs": len(v)}
                              for k, v in sorted(by_style.items()) if v}}
    print(f"{name}: mean {out[name]['mean_ratio']}, median {out[name]['median_ratio']} over {len(allr)} "
          f"section triples; by style {json.dumps(out[name]['by_style'])}")
  if args.json:
    pathlib.Path(args.json).write_text(json.dumps(out, indent=1))
  return out


def _cmd_render(args) -> None:
  d = evaluate.load_dance(args.file, args.audio, args.offset)
  render.render_strip(d.positions, f"{args.out}_strip.png", d.fps, start_s=args.start, n=8, step_s=0.4,
                      title=d.name)
  beats = d.beats()
  speed = metrics.joint_speed(d.positions, d.fps)
  render.render_beats(speed, metrics.motion_beats(d.positions, d.fps), beats, f"{args.out}_beats.png",
                      d.fps, window_s=(args.start, args.start + 10.0),
                      title=f"{d.name}: music beats vs motion beats (speed minima)")
  print(f"wrote {args.out}_strip.png, {args.out}_beats.png")


def main(argv=None) -> int:
  ap = argparse.ArgumentParser(prog="python3 -m training.eval", description=__doc__,
                               formatter_class=argparse.RawDescriptionHelpFormatter)
  sub = ap.add_subparsers(dest="cmd", required=True)
  b = sub.add_parser("baselines")
  b.add_argument("--json")
  m = sub.add_parser("metrics")
  m.add_argument("files", nargs="+")
  m.add_argument("--name", default="evaluated")
  m.add_argument("--audio")
  m.add_argument("--offset", type=float)
  m.add_argument("--json")
  t = sub.add_parser("tempo")
  t.add_argument("--songs", type=int, default=100)
  t.add_argument("--json")
  r = sub.add_parser("render")
  r.add_argument("file")
  r.add_argument("--out", required=True)
  r.add_argument("--start", type=float, default=0.0)
  r.add_argument("--audio")
  r.add_argument("--offset", type=float)
  args = ap.parse_args(argv)
  if args.cmd in ("baselines", "metrics"):
    _cmd_baselines(args)
  elif args.cmd == "tempo":
    _cmd_tempo(args)
  else:
    _cmd_render(args)
  return 0


if __name__ == "__main__":
  sys.exit(main())
