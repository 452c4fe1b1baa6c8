"""One model's full engine measurement: several metric-table draws and tempo following over many seeds.

    .venv/bin/python -m training.eval.engine_suite --model M --out-dir D [--draws 6] [--tempo-seeds 16]
        [--lanes 2] [--summarize-only] [--songs ID,ID --fill-from D0]

Runs `training.eval.engine_eval` once per draw seed (0 .. draws-1) into D/s<seed>/ and
`training.eval.engine_tempo` on seeds 0 .. tempo-seeds-1 split over the lanes (D/tempo_<lane>.json), `lanes`
processes at a time (the engine is single-threaded; two lanes fill this machine's two cores), then writes
D/summary.json and D/summary.md: every draw's FID_k, FID_g, Div_k, Div_g, PFC and jitter with their means,
and the tempo ratio per run over all seeds (mean, bootstrap s.e., median), per song, seeds pooled, and the
ideal-follower calibration. A draw or lane whose output already exists is not run again, so a stopped
suite resumes; --summarize-only only aggregates what is there. Both tools honour DANCE_BUILD_DIR. A
missing motion cache (a fresh checkout) is prepared once first (training.data.prepare, seconds). About
10 min on this 2-core machine with nothing beside it (2026-12-04; up to 17 with other work beside it).

--songs with --fill-from measures a change that touches only some songs (e.g. one style's setting) at
the cost of those songs: only they are generated (draws and tempo), and the other validation songs' dances
and tempo runs are taken from the finished suite D0 (same draw seeds, same tempo seeds), which must be the
same model with the change undone for those songs to be unaffected, so the table is over all songs as usual.

One draw is statistically weak: FID_k of one model varies 16-40 over seeds, the per-run tempo ratio has an
s.e. of ~0.1 on 8 seeds. Compare models on this suite, not on one run.
"""
from __future__ import annotations

import argparse
import json
import pathlib
import re
import subprocess
import sys

import numpy as np

from training.common import clips as td
from training.eval import evaluate, music
from training.eval.engine_tempo import bootstrap_se

METRICS = ("fid_k", "fid_g", "div_k", "div_g", "pfc", "jitter")
MODEL_ROW = "model (engine)"


def _finite(x) -> bool:
  """A ratio that is a number (the reports hold NaN, and JSON null where the calibration had none)."""
  return x is not None and bool(np.isfinite(x))


def draw_commands(model: str, out: pathlib.Path, draws: int, passthrough: list[str]) -> list[tuple[pathlib.Path, list[str]]]:
  """(output that marks it done, command) per metric draw."""
  return [(out / f"s{s}" / "metrics.json",
           [sys.executable, "-m", "training.eval.engine_eval", "--model", model, "--seed", str(s),
            "--out-dir", str(out / f"s{s}")] + passthrough) for s in range(draws)]


def tempo_commands(model: str, out: pathlib.Path, seeds: int, lanes: int,
                   passthrough: list[str]) -> list[tuple[pathlib.Path, list[str]]]:
  """(report path, command) per lane; lane k takes seeds k, k + lanes, ... (balanced). `passthrough` may
  hold --songs."""
  cmds = []
  for lane in range(lanes):
    lane_seeds = [str(s) for s in range(lane, seeds, lanes)]
    if lane_seeds:
      report = out / f"tempo_{lane}.json"
      cmds.append((report, [sys.executable, "-m", "training.eval.engine_tempo", "--model", model, "--seeds",
                            *lane_seeds, "--out", str(report)] + passthrough))
  return cmds


def run_parallel(jobs: list[tuple[pathlib.Path, list[str]]], lanes: int) -> None:
  """Runs the jobs whose output is missing, `lanes` at a time; each logs beside its output. Raises if any
  fails (after the others finish)."""
  todo = [(done, cmd) for done, cmd in jobs if not done.exists()]
  running: list[tuple[pathlib.Path, subprocess.Popen]] = []
  failed = []
  while todo or running:
    while todo and len(running) < lanes:
      done, cmd = todo.pop(0)
      done.parent.mkdir(parents=True, exist_ok=True)
      log = open(done.with_suffix(".log"), "w")
      print("engine_suite: " + " ".join(cmd[1:]), flush=True)
      running.append((done, subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT)))
    done, proc = running.pop(0)
    if proc.wait() != 0 or not done.exists():
      failed.append(str(done.with_suffix(".log")))
  if failed:
    raise RuntimeError("engine_suite: failed, see " + ", ".join(failed))


def tempo_reports(out: pathlib.Path, fill_from: pathlib.Path | None) -> list[dict]:
  """D/tempo_*.json, plus (with fill_from) one report of fill_from's runs of the songs D did not run, on the
  seeds D ran."""
  reports = [json.loads(p.read_text()) for p in sorted(out.glob("tempo_*.json"))]
  if fill_from is None or not reports:
    return reports
  own = {r["id"] for rep in reports for r in rep["rows"]}
  seeds = sorted({s for rep in reports for s in rep["seeds"]})
  filled = []
  for p in sorted(fill_from.glob("tempo_*.json")):
    rep = json.loads(p.read_text())
    for key in ("seconds", "temperature"):
      if any(rep.get(key) != mine.get(key) for mine in reports):
        raise ValueError(f"engine_suite: {p} ran with {key} {rep.get(key)}, this suite with "
                         f"{sorted({str(m.get(key)) for m in reports})}")
    if not own <= {r["id"] for r in rep["rows"]}:
      raise ValueError(f"engine_suite: {p} lacks songs this suite ran ({', '.join(sorted(own))}): "
                       "not a full suite of the same songs")
    if not set(rep["seeds"]) <= set(seeds):
      raise ValueError(f"engine_suite: {p} ran seeds {rep['seeds']}, not all among this suite's {seeds}")
    filled.append({"rows": [r for r in rep["rows"] if r["id"] not in own],
                   "pooled_rows": [r for r in rep["pooled_rows"] if r["id"] not in own],
                   "seeds": rep["seeds"], "filled": True})
  if sorted(s for rep in filled for s in rep["seeds"]) != seeds:
    raise ValueError(f"engine_suite: {fill_from}'s tempo runs are not on this suite's seeds {seeds}")
  return reports + filled


SPAN_METRICS = ("fid_k", "fid_g", "div_k", "div_g")


def span_scores(out: pathlib.Path, draws, fill_from: pathlib.Path | None = None) -> dict | None:
  """FID and Div of each draw's dances cut to the real validation dances' song spans
  (evaluate.on_real_spans: the real row's segments, song for song), beside the real row's; with fill_from
  (a --songs suite) the songs a draw did not generate come from fill_from's draw of the same seed. None when
  a draw has no dance files (a summary of metrics.json files alone) or lacks a validation song."""
  dirs = {s: out / f"s{s}" / "dances" for s in draws}
  if not dirs or any(not d.is_dir() or not any(d.glob("*.json")) for d in dirs.values()):
    return None
  ev = evaluate.Evaluator.default()
  names = {d.name for d in ev.validation}
  scores = {}
  for s, d in dirs.items():
    paths = {p.stem: p for p in (fill_from / f"s{s}" / "dances").glob("*.json")} if fill_from else {}
    paths.update({p.stem: p for p in d.glob("*.json")})
    dances = [evaluate.load_dance(p) for _, p in sorted(paths.items())]  # named by their files' stems
    if {x.name for x in dances} != names:
      return None
    scores[s] = ev.fid_div(evaluate.on_real_spans(dances, ev.validation))
  return {"draws": scores, "mean": {k: float(np.mean([v[k] for v in scores.values()])) for k in SPAN_METRICS},
          "real": ev.fid_div(ev.validation)}


def summarize(out: pathlib.Path, fill_from: pathlib.Path | None = None) -> dict:
  """Aggregates D/s*/metrics.json and D/tempo_*.json (whatever exists; with fill_from, the tempo runs of the
  songs D did not run come from there)."""
  draws = {}
  paths = [p for p in out.glob("s*/metrics.json") if re.fullmatch(r"s\d+", p.parent.name)]
  for path in sorted(paths, key=lambda p: int(p.parent.name[1:])):
    rows = json.loads(path.read_text())
    draws[int(path.parent.name[1:])] = {k: rows[MODEL_ROW][k] for k in METRICS}
    real = {k: rows["real (validation)"][k] for k in METRICS}
  summary: dict = {"draws": draws}
  spans = span_scores(out, sorted(draws), fill_from) if draws else None
  if spans:
    summary["real_spans"] = spans
  if draws:
    summary["draw_mean"] = {k: float(np.mean([d[k] for d in draws.values()])) for k in METRICS}
    # The issue's diversity band: within 20 % of the real dances' on every draw.
    summary["real"] = real
    summary["div_inside_20pct"] = all(abs(d[k] / real[k] - 1) <= 0.2 for d in draws.values() for k in ("div_k", "div_g"))
  rows, pooled, cal, seeds = [], [], [], []
  for rep in tempo_reports(out, fill_from):
    rows += rep["rows"]
    seeds += [] if rep.get("filled") else rep["seeds"]
    pooled += [(r["id"], r["ratio"], len(rep["seeds"])) for r in rep["pooled_rows"]]
    cal += [c for r in rep["pooled_rows"] for c in r.get("perfect_follower_ratios", []) if _finite(c)]
  if rows:
    ratios = [r["ratio"] for r in rows if _finite(r["ratio"])]
    per_song: dict[str, list[float]] = {}
    for r in rows:
      if _finite(r["ratio"]):
        per_song.setdefault(r["id"], []).append(r["ratio"])
    # Pooled ratios are per lane (the seeds of one lane pooled); averaged over lanes, weighted by seeds.
    pooled_song: dict[str, list[tuple[float, int]]] = {}
    for mid, ratio, n in pooled:
      if _finite(ratio):
        pooled_song.setdefault(mid, []).append((ratio, n))
    summary["tempo"] = {
        "songs": sorted({r["id"] for r in rows}), "filled_from": str(fill_from) if fill_from else None,
        "seeds": sorted(seeds), "runs": len(rows), "finite_runs": len(ratios),
        "mean_ratio": float(np.mean(ratios)), "mean_ratio_se": bootstrap_se(ratios),
        "median_ratio": float(np.median(ratios)),
        # The mean ratio counts an overshoot (a dance whose period changes more than the music's) as a gain;
        # the distance from 1 does not: 0 = every run follows exactly.
        "mean_abs_error": float(np.mean(np.abs(np.asarray(ratios) - 1.0))),
        "within_20pct": float(np.mean(np.abs(np.asarray(ratios) - 1.0) <= 0.2)),
        "per_song": {m: float(np.mean(v)) for m, v in sorted(per_song.items())},
        "pooled_per_song": {m: float(sum(r * n for r, n in v) / sum(n for _, n in v))
                            for m, v in sorted(pooled_song.items())},
        "perfect_follower_mean_ratio": float(np.mean(cal)) if cal else None}
    ps = summary["tempo"]["pooled_per_song"]
    summary["tempo"]["pooled_mean_ratio"] = float(np.mean(list(ps.values()))) if ps else None
  return summary


def markdown(summary: dict, model: str) -> str:
  lines = [f"# engine suite: {model}", ""]
  if summary["draws"]:
    lines += ["| draw | " + " | ".join(METRICS) + " |", "|---" * (len(METRICS) + 1) + "|"]
    for s, d in summary["draws"].items():
      lines.append(f"| seed {s} | " + " | ".join(f"{d[k]:.4g}" for k in METRICS) + " |")
    lines.append("| **mean** | " + " | ".join(f"{summary['draw_mean'][k]:.4g}" for k in METRICS) + " |")
    lines.append("| real (validation) | " + " | ".join(f"{summary['real'][k]:.4g}" for k in METRICS) + " |")
    lines += ["", f"Div_k and Div_g within 20 % of real on every draw: {summary['div_inside_20pct']}", ""]
    sp = summary.get("real_spans")
    if sp:
      n = sp["real"]["segments"]
      lines += [f"On the real dances' spans (each draw cut to the song time the real dance covers: {n} segments, "
                "song for song, as the real row; evaluate.on_real_spans):", "",
                "| draw | " + " | ".join(SPAN_METRICS) + " |", "|---" * (len(SPAN_METRICS) + 1) + "|"]
      for s, d in sp["draws"].items():
        lines.append(f"| seed {s} | " + " | ".join(f"{d[k]:.4g}" for k in SPAN_METRICS) + " |")
      lines.append("| **mean** | " + " | ".join(f"{sp['mean'][k]:.4g}" for k in SPAN_METRICS) + " |")
      lines.append("| real (validation) | " + " | ".join(f"{sp['real'][k]:.4g}" for k in SPAN_METRICS) + " |")
      lines.append("")
  t = summary.get("tempo")
  if t:
    def num(x) -> str:  # None: too few runs for it (one run has no s.e.; no pooled or calibration rows)
      return "n/a" if x is None else f"{x:.3f}"
    filled = f"; songs it did not run from {t['filled_from']}" if t.get("filled_from") else ""
    lines += [f"Tempo following over {len(t.get('songs', []))} songs, {len(t['seeds'])} seeds ({t['finite_runs']}/"
              f"{t['runs']} runs{filled}): per run mean "
              f"**{num(t['mean_ratio'])}** (s.e. {num(t['mean_ratio_se'])}), median {num(t['median_ratio'])}; seeds "
              f"pooled {num(t['pooled_mean_ratio'])}; ideal follower with this spread "
              f"{num(t['perfect_follower_mean_ratio'])}; mean |ratio - 1| per run {num(t.get('mean_abs_error'))}, "
              f"runs within 0.2 of 1: {num(t.get('within_20pct'))}",
              "", "| song | per run | pooled |", "|---|---|---|"]
    for m, v in t["per_song"].items():
      lines.append(f"| {m} | {v:.3f} | {t['pooled_per_song'].get(m, float('nan')):.3f} |")
  return "\n".join(lines) + "\n"


def main(argv=None) -> None:
  ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  ap.add_argument("--model", required=True)
  ap.add_argument("--out-dir", required=True)
  ap.add_argument("--draws", type=int, default=6)
  ap.add_argument("--tempo-seeds", type=int, default=16)
  ap.add_argument("--lanes", type=int, default=2)
  ap.add_argument("--summarize-only", action="store_true")
  ap.add_argument("--temperature", type=float, default=None)
  ap.add_argument("--guidance", type=float, default=None)
  ap.add_argument("--top-p", type=float, default=None)
  ap.add_argument("--period-lock", type=float, default=None)
  ap.add_argument("--songs", default=None, help="comma-separated motion ids (default: every validation song); "
                  "needs --fill-from")
  ap.add_argument("--fill-from", default=None, help="a finished suite of the same model whose dances and tempo "
                  "runs of the songs not in --songs are used")
  args = ap.parse_args(argv)
  if (args.songs is None) != (args.fill_from is None):
    ap.error("--songs and --fill-from go together")
  fill = pathlib.Path(args.fill_from) if args.fill_from else None
  out = pathlib.Path(args.out_dir)
  out.mkdir(parents=True, exist_ok=True)
  passthrough = []
  for flag in ("temperature", "guidance", "top_p", "period_lock"):
    if getattr(args, flag) is not None:
      passthrough += ["--" + flag.replace("_", "-"), str(getattr(args, flag))]
  subset = ["--songs", args.songs] if args.songs else []
  if not args.summarize_only:
    # Once, before the parallel draws: each would otherwise find the motion cache missing on a fresh checkout
    # and prepare it at the same time as the others.
    td.ensure_motion_cache()
    # and librosa's beat tracker compiled here, so that parallel lanes only read its numba cache
    # (music.warm_librosa: lanes compiling it at once corrupted it, 2026-12-06)
    music.warm_librosa()
    run_parallel(draw_commands(args.model, out, args.draws, passthrough + subset +
                               (["--fill-from", args.fill_from] if fill else [])), args.lanes)
    run_parallel(tempo_commands(args.model, out, args.tempo_seeds, args.lanes, passthrough + subset), args.lanes)
  summary = summarize(out, fill)
  (out / "summary.json").write_text(json.dumps(summary, indent=1))
  text = markdown(summary, args.model)
  (out / "summary.md").write_text(text)
  print(text)


if __name__ == "__main__":
  main()
