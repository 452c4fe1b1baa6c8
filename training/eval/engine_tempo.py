"""Tempo following of the product itself: the C++ engine (`dance-generate`) on time-stretched songs.

For each song and seed: the first `--seconds` of the song (sox trim), and that excerpt stretched to 0.85x
and 1.15x with `sox tempo` (pitch kept); `dance-generate` dances to each; training.eval.tempo fits how the
dance's dominant period scales with the music (1 = follows exactly, 0 = ignores the music). Reported per
run (song x seed) and with the seeds pooled per song (the dominant period of the seeds' mean speed
autocorrelation: one random dance's period is a noisy estimate of the generator's, per-run ratios of the
same model spread over about -1.5..2). Beside them, a calibration of the per-run statistic from the same
dances: an ideal follower whose draws vary like this model's (seed s's dance to the original; for the music
stretched by 0.85 / 1.15, the dances of the next two seeds in --seeds (wrapping) to the original played
exactly that much faster; tempo.perfect_follower_ratio; needs >= 3 seeds). It treats the three versions'
dances as independent draws; a real run dances them with one seed, so if same-seed draws are correlated the
true ceiling is higher than this calibration says.
and the spread of the base period over seeds (std of its log) per song.

    /usr/bin/python3 -m training.eval.engine_tempo --model models/default.dncw [--songs validation]
        [--seeds 0 1] [--seconds 60] [--temperature T] [--period-lock B] [--out report.json]

Needs `dance-generate` (DANCE_BUILD_DIR, default build/) and sox.
"""
from __future__ import annotations

import argparse
import json
import pathlib
import subprocess
import tempfile

import numpy as np

from training import tools
from training.common import clips as td
from training.eval.tempo import dominant_period, perfect_follower_ratio, pooled_tempo_following, tempo_following

REPO = pathlib.Path(__file__).resolve().parents[2]


def generate(model: str, audio: str, seed: int, style: str, workdir: pathlib.Path,
             temperature: float = 1.0, top_p: float | None = None, guidance: float | None = None,
             period_lock: float | None = None) -> np.ndarray:
  """Runs dance-generate on `audio`; returns positions (T, 24, 3) at 30 fps. top_p, guidance and period_lock
  None = the model's defaults."""
  out = workdir / (pathlib.Path(audio).stem + f"_s{seed}.json")
  if out.is_file():  # already danced in this run (same model and settings: the workdir is per run)
    return np.asarray(json.loads(out.read_text())["positions"], dtype=np.float64)
  tools.dance_generate(model, audio, out, seed=seed, temperature=temperature, style=style, top_p=top_p,
                       guidance=guidance, period_lock=period_lock)
  return np.asarray(json.loads(out.read_text())["positions"], dtype=np.float64)


def song_excerpt(audio: str, seconds: float, dst: pathlib.Path) -> str:
  # Float output: no (random) dither, so every run dances to the same samples.
  subprocess.run(["sox", audio, "-e", "floating-point", "-b", "32", "-r", "24000", "-c", "1", str(dst), "trim", "0",
                  str(seconds)], check=True, capture_output=True)
  return str(dst)


def bootstrap_se(values, n_boot: int = 2000) -> float | None:
  """Standard error of the mean of `values` by bootstrap over runs (fixed generator: repeatable). The per-run
  ratio is heavy-tailed (one mis-picked period gives -2 or +2), so 8 seeds x 8 songs leave an s.e. of ~0.1:
  compare models on 16 seeds or more."""
  v = np.asarray(values, dtype=np.float64)
  if len(v) < 2:
    return None
  rng = np.random.default_rng(0)
  return float(np.std(v[rng.integers(0, len(v), size=(n_boot, len(v)))].mean(axis=1)))


def measure(model: str, songs: str = "validation", seeds=(0, 1), seconds: float = 60.0, temperature: float = 1.0,
            top_p: float | None = None, guidance: float | None = None, period_lock: float | None = None) -> dict:
  """The tempo-following report of `model` (module docstring): songs "validation", "train" or comma-separated
  motion ids; top_p, guidance and period_lock None = the model's defaults. Prints a line per run and song."""
  seeds = [int(s) for s in seeds]
  td.ensure_motion_cache()  # the songs' audio paths and styles (a fresh checkout has no cache yet)
  if len(seeds) < 3:
    print("engine_tempo: fewer than 3 seeds: the ideal-follower calibration is skipped", flush=True)
  split = td.load_split()
  ids = td.tang_ids(split[songs]) if songs in ("validation", "train") else songs.split(",")
  rows, pooled = [], []
  with tempfile.TemporaryDirectory() as tmp:
    work = pathlib.Path(tmp)
    for mid in ids:
      z = np.load(td.MOTION_CACHE / f"{mid}.npz")
      excerpt = song_excerpt(str(z["audio_path"]), seconds, work / f"{mid}.wav")
      for seed in seeds:
        gen = lambda path, seed=seed, style=str(z["style"]): generate(  # noqa: E731
            model, path, seed, style, work, temperature, top_p, guidance, period_lock)
        r = tempo_following(gen, excerpt, work)
        r.update(id=mid, seed=seed)
        rows.append(r)
        print(f"{mid} seed {seed}: ratio {r['ratio']:.3f}  periods {r['base_period_s']:.3f} -> "
              f"{['%.3f' % p for p in r['periods_s']]}", flush=True)
      # The same songs with the seeds pooled: the mean speed autocorrelation of all seeds' dances.
      gen_many = lambda path, style=str(z["style"]): [generate(  # noqa: E731
          model, path, seed, style, work, temperature, top_p, guidance, period_lock) for seed in seeds]
      r = pooled_tempo_following(gen_many, excerpt, work)
      base = gen_many(excerpt)
      if len(base) > 2:
        n = len(base)
        cal = [perfect_follower_ratio(base[i], [base[(i + 1) % n], base[(i + 2) % n]]) for i in range(n)]
        periods = np.array([dominant_period(d) for d in base])
        r.update(perfect_follower_ratios=cal, base_period_log_std=float(np.nanstd(np.log(periods))))
      r.update(id=mid)
      pooled.append(r)
      print(f"{mid} pooled over seeds {seeds}: ratio {r['ratio']:.3f}  periods {r['base_period_s']:.3f} -> "
            f"{['%.3f' % p for p in r['periods_s']]}", flush=True)
  ratios = [r["ratio"] for r in rows if np.isfinite(r["ratio"])]
  pooled_ratios = [r["ratio"] for r in pooled if np.isfinite(r["ratio"])]
  cal = [c for r in pooled for c in r.get("perfect_follower_ratios", []) if np.isfinite(c)]
  report = {"model": model, "seconds": seconds, "temperature": temperature,
            "top_p": top_p, "guidance": guidance, "period_lock": period_lock, "seeds": seeds,
            "mean_ratio": float(np.mean(ratios)) if ratios else None,
            "mean_ratio_se": bootstrap_se(ratios),
            "median_ratio": float(np.median(ratios)) if ratios else None, "runs": len(rows),
            "finite_runs": len(ratios), "rows": rows,
            "pooled_mean_ratio": float(np.mean(pooled_ratios)) if pooled_ratios else None,
            "pooled_finite_songs": len(pooled_ratios), "pooled_rows": pooled,
            "perfect_follower_mean_ratio": float(np.mean(cal)) if cal else None,
            "perfect_follower_median_ratio": float(np.median(cal)) if cal else None}
  print(f"per run: mean ratio {report['mean_ratio']} (bootstrap s.e. {report['mean_ratio_se']}), median "
        f"{report['median_ratio']} over "
        f"{len(ratios)}/{len(rows)} runs; seeds pooled: mean ratio {report['pooled_mean_ratio']} over "
        f"{len(pooled_ratios)}/{len(pooled)} songs; an ideal follower with this model's draw-to-draw spread: "
        f"mean {report['perfect_follower_mean_ratio']}, median {report['perfect_follower_median_ratio']}")
  return report


def write_report(report: dict, path) -> None:
  """`report` as strict JSON (NaN as null)."""
  clean = lambda v: (None if isinstance(v, float) and not np.isfinite(v) else  # noqa: E731
                     [clean(x) for x in v] if isinstance(v, list) else
                     {k: clean(x) for k, x in v.items()} if isinstance(v, dict) else v)
  pathlib.Path(path).write_text(json.dumps(clean(report), indent=1, allow_nan=False))


def main(argv=None) -> None:
  ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  ap.add_argument("--model", default=str(REPO / "models" / "default.dncw"))
  ap.add_argument("--songs", default="validation", help="validation, train, or comma-separated motion ids")
  ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
  ap.add_argument("--seconds", type=float, default=60.0)
  ap.add_argument("--temperature", type=float, default=1.0)
  ap.add_argument("--top-p", type=float, default=None, help="dance-generate --top-p (default: the model's)")
  ap.add_argument("--guidance", type=float, default=None,
                  help="style guidance (dance-generate --guidance; default: the model's)")
  ap.add_argument("--period-lock", type=float, default=None,
                  help="dance-generate --period-lock (default: the model's; 0 = off)")
  ap.add_argument("--out", default=None)
  args = ap.parse_args(argv)
  report = measure(args.model, args.songs, args.seeds, args.seconds, args.temperature, args.top_p, args.guidance,
                   args.period_lock)
  if args.out:
    write_report(report, args.out)


if __name__ == "__main__":
  main()
