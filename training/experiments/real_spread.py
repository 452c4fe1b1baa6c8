"""How much the real row's FID depends on which songs validate: the FID_k / FID_g of real held-out song sets
with the validation's composition, each scored as the real row is (normaliser fitted on the held-out set,
reference = every other paired Tang dance), over many random sets.

    /usr/bin/python3 -m training.experiments.real_spread [--draws 1000] [--seed 0] [--compare FID_K FID_G]

The validation set has one cha-cha, one rumba, the tango's last quarter and five waltzes. A random set draws
the same numbers per style from all paired Tang dances; the tango, a single dance cut in time, always holds
out its validation part (T_5_b), so the tango's training part (T_5_a) stays in every reference. Read a
model's FID (scored against the fixed split) beside both the official real row and this spread: the spread
is the FID a real dancer's set scores when the held-out songs differ, which sets how close "close to
real" can be read (docs/evaluation.md).
"""
from __future__ import annotations

import argparse

import numpy as np

from training.eval import metrics
from training.eval.evaluate import cached_dances, segment_table, split_ids

FIXED = ("tang_DANCE_T_5_b",)  # held out in every set (the only tango's validation part)
EXCLUDED_FROM_DRAWS = ("tang_DANCE_T_5_a",)


def style_letter(motion_id: str) -> str:
  return motion_id.split("_")[2]


def held_out_fid(tables: dict[str, dict], held_out: list[str]) -> tuple[float, float]:
  """FID_k, FID_g of the held-out songs' segments against all other songs' (the Evaluator's recipe:
  normalisers fitted on the held-out set, geometric floor 0.05)."""
  ref = [i for i in tables if i not in held_out]
  vk = np.concatenate([tables[i]["kinetic"] for i in held_out])
  vg = np.concatenate([tables[i]["geometric"] for i in held_out])
  rk = np.concatenate([tables[i]["kinetic"] for i in ref])
  rg = np.concatenate([tables[i]["geometric"] for i in ref])
  nk, ng = metrics.FeatureStats.fit(vk), metrics.FeatureStats.fit(vg, floor=0.05)
  return (metrics.frechet_distance(nk.apply(rk), nk.apply(vk)),
          metrics.frechet_distance(ng.apply(rg), ng.apply(vg)))


def random_sets(ids: list[str], validation: list[str], draws: int, seed: int = 0) -> list[list[str]]:
  """`draws` held-out sets with the validation's count per style, drawn without replacement within a
  style from `ids` (FIXED always in, EXCLUDED_FROM_DRAWS never drawn)."""
  rng = np.random.default_rng(seed)
  pool: dict[str, list[str]] = {}
  for i in ids:
    if i not in FIXED and i not in EXCLUDED_FROM_DRAWS:
      pool.setdefault(style_letter(i), []).append(i)
  counts: dict[str, int] = {}
  for v in validation:
    if v not in FIXED:
      counts[style_letter(v)] = counts.get(style_letter(v), 0) + 1
  out = []
  for _ in range(draws):
    s = list(FIXED)
    for style, n in sorted(counts.items()):
      s += list(rng.choice(pool[style], n, replace=False))
    out.append(s)
  return out


def spread(tables: dict[str, dict], validation: list[str], draws: int, seed: int = 0,
           compare: tuple[float, float] | None = None) -> dict:
  """The official set's FIDs, the random sets' FIDs, and where the official set falls among them; with
  `compare` (a model's FID_k, FID_g) also the share of random sets scoring at least as much."""
  official = held_out_fid(tables, validation)
  sets = random_sets(list(tables), validation, draws, seed)
  f = np.array([held_out_fid(tables, s) for s in sets])
  out = {"official": {"fid_k": official[0], "fid_g": official[1]}, "draws": draws}
  for j, key in enumerate(("fid_k", "fid_g")):
    out[key] = {"mean": float(f[:, j].mean()),
                **{f"p{q}": float(np.percentile(f[:, j], q)) for q in (10, 25, 50, 75, 90)},
                "official_percentile": float((f[:, j] < official[j]).mean() * 100),
                "max": float(f[:, j].max())}
    if compare is not None:
      out[key]["share_at_least_compare"] = float((f[:, j] >= compare[j]).mean())
  return out


def main(argv=None) -> None:
  ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
  ap.add_argument("--draws", type=int, default=1000)
  ap.add_argument("--seed", type=int, default=0)
  ap.add_argument("--compare", type=float, nargs=2, metavar=("FID_K", "FID_G"),
                  help="a model's FIDs (e.g. engine_suite's means on the real spans): the share of real sets "
                       "scoring at least as much")
  args = ap.parse_args(argv)
  if args.draws < 1:
    ap.error("--draws must be at least 1")
  validation = split_ids("validation")
  ids = split_ids("train") + validation
  tables = {d.name: segment_table([d], beats_of=lambda _d: np.zeros(0)) for d in cached_dances(ids)}
  r = spread(tables, validation, args.draws, args.seed, args.compare)
  print(f"official validation set: FID_k {r['official']['fid_k']:.2f}, FID_g {r['official']['fid_g']:.2f}")
  print(f"{args.draws} random held-out sets of the same composition (percentiles 10 / 25 / 50 / 75 / 90):")
  for key, label in (("fid_k", "FID_k"), ("fid_g", "FID_g")):
    s = r[key]
    print(f"  {label}: mean {s['mean']:.2f}; {s['p10']:.2f} / {s['p25']:.2f} / {s['p50']:.2f} / {s['p75']:.2f} / "
          f"{s['p90']:.2f}; max {s['max']:.2f}; the official set lies at percentile {s['official_percentile']:.0f}")
    if args.compare:
      print(f"    real sets scoring at least {args.compare[key == 'fid_g']:.2f}: "
            f"{100 * s['share_at_least_compare']:.1f} %")


if __name__ == "__main__":
  main()
