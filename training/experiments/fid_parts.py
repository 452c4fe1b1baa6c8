"""Where a FID_k comes from: the mean and covariance terms of the kinetic Frechet distance, the kinetic
dimensions whose averages differ most from the real training dances', per style the horizontal kinetic
energy of the torso and wrists and the turn rate, and per style its reach (style_reach), for dance sets
beside the real validation dances.

    /usr/bin/python3 -m training.experiments.fid_parts D/s0/dances [D/s1/dances ...] [--top 12] [--spans]
        [--leave-one-out] [--song-means]

Each argument is a directory of dance JSON files (an engine_eval draw's `dances/`); all of them are pooled
for the per-style table and the top dimensions, and each gets its own FID_k split. The split uses the same
features, normaliser and reference as training.eval.evaluate (so FID_k equals engine_eval's).
--spans cuts every dance to the song time its real counterpart covers first (evaluate.on_real_spans: the
real row's segments, song for song). --leave-one-out adds, per validation song, the FID_k and FID_g of the
real validation and of the dances (mean over the directories) without that song, and their excess over
real: which songs the excess comes from. --song-means (with --spans) splits the excess between the songs'
average features and the spread within each song: FID of the dances with each song's segments moved to the
real dance's average for that song (keeping the model's variation within the song), of the real segments
moved to the model's song averages, and of the dances moved to the real training dances' average for the
song's style; then per song how far the model's average lies from the real one and from the style's.
"""
from __future__ import annotations

import argparse
import glob
import pathlib

import numpy as np

from training.data.skeleton import JOINT_NAMES
from training.eval import metrics
from training.eval.evaluate import Evaluator, load_dance, on_real_spans, segment_table

KINDS = ("ke_h", "ke_v", "ee")  # features.kinetic_features: per joint, in this order
STYLE_JOINTS = ("spine3", "neck", "head", "left_wrist", "left_knee")


def _no_beats(_dance):
  return np.zeros(0)


def style_of(name: str) -> str:
  """tang_DANCE_W_3 -> W (the Tang style letter); other names whole."""
  parts = name.split("_")
  return parts[2] if len(parts) > 2 and parts[0] == "tang" else name


def per_style(table: dict) -> dict[str, dict]:
  kin = table["kinetic"].reshape(len(table["rows"]), len(JOINT_NAMES), len(KINDS))
  out: dict[str, list] = {}
  for row, k in zip(table["rows"], kin):
    vals = [k[JOINT_NAMES.index(j), 0] for j in STYLE_JOINTS] + [row["turn_rate"]]
    out.setdefault(style_of(row["dance"]), []).append(vals)
  return {s: {"segments": len(v), **dict(zip(STYLE_JOINTS + ("turn_rate",), np.mean(v, 0)))}
          for s, v in sorted(out.items())}


def style_reach(ref: np.ndarray, ref_rows: list, x: np.ndarray, rows: list) -> dict[str, float]:
  """How far each style's mean kinetic features go along the real style's own direction: the projection of
  (style mean of x - the reference's mean) on (the reference's style mean - its mean), divided by that
  direction's squared length. 1 = as distinct as the real training dances of the style, 0 = the average
  dance (all styles blended), above 1 = overdone. Normalised features (the evaluator's)."""
  def styles(rows_):
    return np.array([style_of(r["dance"]) for r in rows_])
  rs, xs = styles(ref_rows), styles(rows)
  mean = ref.mean(0)
  out = {}
  for st in sorted(set(xs) & set(rs)):
    direction = ref[rs == st].mean(0) - mean
    out[st] = float(np.dot(x[xs == st].mean(0) - mean, direction) / np.dot(direction, direction))
  return out


def leave_one_out(ev, val: dict, draws: list[dict]) -> list[dict]:
  """Per song (and "none" first), FID_k / FID_g of the real validation segments and the mean over `draws`
  (segment tables) without that song's segments."""
  def names(t):
    return np.array([r["dance"] for r in t["rows"]])
  def fids(t, song):
    keep = names(t) != song
    return (metrics.frechet_distance(ev.ref_k, ev.norm_k.apply(t["kinetic"][keep])),
            metrics.frechet_distance(ev.ref_g, ev.norm_g.apply(t["geometric"][keep])))
  out = []
  for song in ["none"] + sorted(set(names(val))):
    rk, rg = fids(val, song)
    gk, gg = np.mean([fids(t, song) for t in draws], axis=0)
    out.append({"without": song, "real_k": rk, "real_g": rg, "model_k": float(gk), "model_g": float(gg),
                "excess_k": float(gk - rk), "excess_g": float(gg - rg)})
  return out


def _names(t: dict) -> np.ndarray:
  return np.array([r["dance"] for r in t["rows"]])


def _moved_to(x: np.ndarray, names: np.ndarray, means: dict) -> np.ndarray:
  """Each song's rows of x shifted so that their average is means[song]."""
  out = x.copy()
  for song in set(names):
    rows = names == song
    out[rows] += means[song] - x[rows].mean(0)
  return out


def song_mean_swap(ev, val: dict, draws: list[dict]) -> dict:
  """Where the excess sits: between-song averages or within-song spread (docs/evaluation.md). For FID_k and
  FID_g, means over `draws` (segment tables of the dances on the real spans, the same songs as `val`):
  model; model_within_real_means (each song's generated segments moved to the real song average);
  real_within_model_means (the real segments moved to the generated song averages);
  model_within_style_means (moved to the real training dances' average of the song's style). Also per song
  (kinetic): |model average - real average|, |real average - style average|, |model average - style
  average|."""
  ref_style = np.array([style_of(r["dance"]) for r in ev.ref_rows])
  vn = _names(val)
  out: dict = {"per_song": {}}
  for kind, ref, norm in (("k", ev.ref_k, ev.norm_k), ("g", ev.ref_g, ev.norm_g)):
    key = "kinetic" if kind == "k" else "geometric"
    v = norm.apply(val[key])
    real_means = {s: v[vn == s].mean(0) for s in set(vn)}
    style_means = {s: ref[ref_style == style_of(s)].mean(0) for s in set(vn)}
    rows = []
    for t in draws:
      g, gn = norm.apply(t[key]), _names(t)
      if set(gn) != set(vn):
        raise ValueError("song_mean_swap: the draws must cover the real dances' songs (use the spans)")
      gen_means = {s: g[gn == s].mean(0) for s in set(gn)}
      rows.append([metrics.frechet_distance(ref, g), metrics.frechet_distance(ref, _moved_to(g, gn, real_means)),
                   metrics.frechet_distance(ref, _moved_to(v, vn, gen_means)),
                   metrics.frechet_distance(ref, _moved_to(g, gn, style_means))])
      if kind == "k":
        for s in gen_means:
          out["per_song"].setdefault(s, []).append(gen_means[s])
    m = np.mean(rows, axis=0)
    out[kind] = {"model": m[0], "model_within_real_means": m[1], "real_within_model_means": m[2],
                 "model_within_style_means": m[3], "real": metrics.frechet_distance(ref, v)}
    if kind == "k":
      out["per_song"] = {s: {"model_real": float(np.linalg.norm(np.mean(gm, 0) - real_means[s])),
                             "real_style": float(np.linalg.norm(real_means[s] - style_means[s])),
                             "model_style": float(np.linalg.norm(np.mean(gm, 0) - style_means[s])),
                             "segments": int(np.sum(vn == s))}
                         for s, gm in sorted(out["per_song"].items())}
  return out


def main(argv=None) -> None:
  ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
  ap.add_argument("dirs", nargs="+", help="directories of dance JSON files")
  ap.add_argument("--top", type=int, default=12, help="how many kinetic dimensions to list")
  ap.add_argument("--spans", action="store_true", help="cut each dance to its real counterpart's song span")
  ap.add_argument("--leave-one-out", action="store_true", help="FID without each validation song in turn")
  ap.add_argument("--song-means", action="store_true",
                  help="with --spans: the excess split between the songs' averages and the spread within songs")
  args = ap.parse_args(argv)
  if args.song_means and not args.spans:
    ap.error("--song-means needs --spans (the same songs and segments as the real dances)")
  ev = Evaluator.default()
  val = segment_table(ev.validation, beats_of=_no_beats)
  vk = ev.norm_k.apply(val["kinetic"])
  m, c = metrics.frechet_parts(ev.ref_k, vk)
  print(f"real (validation): FID_k {m + c:.2f} = mean term {m:.2f} + covariance term {c:.2f} ({len(vk)} segments)")
  pooled, raw, rows, tables = [], [], [], []
  for d in args.dirs:
    files = sorted(glob.glob(str(pathlib.Path(d) / "*.json")))
    dances = [load_dance(p) for p in files]
    if not dances:
      raise SystemExit(f"fid_parts: no dance JSON files in {d}")
    if args.spans:
      dances = on_real_spans(dances, ev.validation)
    t = segment_table(dances, beats_of=_no_beats)
    tables.append(t)
    k = ev.norm_k.apply(t["kinetic"])
    m, c = metrics.frechet_parts(ev.ref_k, k)
    print(f"{d}: FID_k {m + c:.2f} = mean term {m:.2f} + covariance term {c:.2f} ({len(k)} segments)")
    pooled.append(k)
    raw.append(t["kinetic"])
    rows += t["rows"]
  k = np.concatenate(pooled)
  diff = k.mean(0) - ev.ref_k.mean(0)
  names = [f"{j}.{kind}" for j in JOINT_NAMES for kind in KINDS]
  print(f"\nkinetic dimensions furthest from the real training dances' mean (normalised units; pooled):")
  for i in np.argsort(-diff ** 2)[:args.top]:
    print(f"  {names[i]:<20} generated - real {diff[i]:+.2f}   std generated {k[:, i].std():.2f}, "
          f"real train {ev.ref_k[:, i].std():.2f}")
  ratio = (k.std(0) / ev.ref_k.std(0)).reshape(len(JOINT_NAMES), len(KINDS)).mean(0)
  print("spread generated / real train, mean over joints: " +
        ", ".join(f"{kind} {r:.2f}" for kind, r in zip(KINDS, ratio)))
  gen = {"kinetic": np.concatenate(raw), "rows": rows}
  reach_val = style_reach(ev.ref_k, ev.ref_rows, vk, val["rows"])
  reach_gen = style_reach(ev.ref_k, ev.ref_rows, k, rows)
  print("\nstyle reach (kinetic; 1 = as distinct as the real training dances of the style, 0 = blended): " +
        ", ".join(f"{st} {reach_gen[st]:.2f} (real validation {reach_val.get(st, float('nan')):.2f})"
                  for st in reach_gen))
  if args.leave_one_out:
    print("\nleaving one validation song out of both sides (model: mean over the directories):")
    for r in leave_one_out(ev, val, tables):
      print(f"  without {r['without']:<18} FID_k real {r['real_k']:6.2f} model {r['model_k']:6.2f} excess "
            f"{r['excess_k']:+6.2f} | FID_g real {r['real_g']:5.2f} model {r['model_g']:5.2f} excess {r['excess_g']:+5.2f}")
  if args.song_means:
    sw = song_mean_swap(ev, val, tables)
    print("\nsong averages against spread within songs (mean over the directories; FID_k / FID_g):")
    for key, label in (("model", "model"), ("model_within_real_means", "model, each song moved to the real "
                       "song's average"), ("real_within_model_means", "real, each song moved to the model's "
                       "song average"), ("model_within_style_means", "model, each song moved to its style's "
                       "real training average"), ("real", "real")):
      print(f"  {label:<66} {sw['k'][key]:6.2f} / {sw['g'][key]:5.2f}")
    print("  per song (kinetic, normalised units): |model - real average|, |real - style average|, "
          "|model - style average|")
    for song, r in sw["per_song"].items():
      print(f"    {song:<18} {r['model_real']:6.2f} {r['real_style']:6.2f} {r['model_style']:6.2f}  "
            f"({r['segments']} segments)")
  print(f"\nper style: horizontal kinetic energy (m^2/s^2) of {', '.join(STYLE_JOINTS)}; turn rate (rad/s)")
  for label, table in (("real", val), ("generated", gen)):
    for style, v in per_style(table).items():
      print(f"  {label:<9} {style:<4} {v['segments']:4d} segs  " +
            "  ".join(f"{v[j]:.3f}" for j in STYLE_JOINTS) + f"  turn {v['turn_rate']:.2f}")


if __name__ == "__main__":
  main()
