"""Converts every motion source to the canonical skeleton and writes training/cache/motion/<id>.npz.

Run from the repository root:
  /usr/bin/python3 -m training.data.prepare [--data ../shared/data] [--aistpp DIR] [--force] [--tang-sides lady]

Idempotent: a cache file is rewritten only when it is missing, was written by another converter version,
or --force is given. Also writes training/split.json when it is missing, older than make_split's version, or
names other ids than were converted (e.g. after adding --aistpp); it is committed and fixed in code. Each npz holds:
  positions (T, 24, 3) float32, metres, Y up, canonical bone lengths, 30 fps
  fps () float, style () str, source () str, audio_path () str ("" without audio),
  audio_offset_s () float: song time of frame 0, converter_version () int, notes () str (JSON)
"""
from __future__ import annotations

import argparse
import json
import pathlib
import sys

import numpy as np

from training.data import aistpp, sources
from training.data import skeleton as sk

CONVERTER_VERSION = 3
REPO = pathlib.Path(__file__).resolve().parents[2]
CACHE = REPO / "training" / "cache" / "motion"
SPLIT_PATH = REPO / "training" / "split.json"
# Tang has a single tango; it is cut in time: the first part trains, the last VALIDATION_TAIL validates.
TANGO_SPLIT_FRACTION = 0.75


def _save(path: pathlib.Path, m: sources.Motion) -> None:
  tmp = path.with_suffix(".tmp.npz")
  np.savez_compressed(tmp, positions=m.positions.astype(np.float32), fps=np.float64(m.fps),
                      style=np.str_(m.style), source=np.str_(m.source),
                      audio_path=np.str_(m.audio_path), audio_offset_s=np.float64(m.audio_offset_s),
                      converter_version=np.int64(CONVERTER_VERSION), notes=np.str_(json.dumps(m.notes)))
  tmp.replace(path)


def _fresh(path: pathlib.Path, tang_sides: str | None = None) -> bool:
  """Whether the cache file is this converter's (and, with tang_sides, of that reading of the Tang sides;
  files written before the option are "captured")."""
  if not path.exists():
    return False
  try:
    with np.load(path) as z:
      if int(z["converter_version"]) != CONVERTER_VERSION:
        return False
      return tang_sides is None or json.loads(str(z["notes"])).get("tang_sides", "captured") == tang_sides
  except Exception:  # unreadable or truncated: rebuild
    return False


def load_motion(motion_id: str, cache: pathlib.Path = CACHE) -> dict:
  """Reads one cache entry as a dict of numpy values (strings as str, scalars as float)."""
  with np.load(cache / f"{motion_id}.npz") as z:
    out = {k: z[k] for k in z.files}
  for k in ("style", "source", "audio_path", "notes"):
    out[k] = str(out[k])
  for k in ("fps", "audio_offset_s"):
    out[k] = float(out[k])
  return out


def _split_tango(m: sources.Motion) -> tuple[sources.Motion, sources.Motion]:
  t = m.positions.shape[0]
  cut = int(t * TANGO_SPLIT_FRACTION) // 4 * 4
  a = sources.Motion(m.positions[:cut], m.fps, m.style, m.source, m.audio_path, m.audio_offset_s,
                     dict(m.notes, part="first", frames=[0, cut]))
  b = sources.Motion(sk.put_on_floor(m.positions[cut:].astype(np.float64)).astype(np.float32), m.fps,
                     m.style, m.source, m.audio_path, m.audio_offset_s + cut / m.fps,
                     dict(m.notes, part="last", frames=[cut, t]))
  return a, b


def jobs(data: pathlib.Path, skel: sk.Skeleton, tang_sides: str = sources.TANG_SIDES_DEFAULT):
  """Yields (ids, thunk) where thunk() returns the Motions for those ids."""
  for folder in sorted((data / "tang2018").glob("DANCE_*")):
    if folder.name.startswith("DANCE_T_"):
      yield ([f"tang_{folder.name}_a", f"tang_{folder.name}_b"],
             lambda f=folder: _split_tango(sources.convert_tang(f, skel, tang_sides)))
    else:
      yield [f"tang_{folder.name}"], lambda f=folder: [sources.convert_tang(f, skel, tang_sides)]
  for path in sorted((data / "mocap" / "cmu_salsa").glob("*.bvh")):
    yield ([f"cmu_{path.stem.replace('_scaled', '')}"],
           lambda p=path: [sources.convert_bvh(p, sources.CMU_MAP, 1.0, "salsa", "cmu_salsa", skel)])
  for path in sorted((data / "mocap" / "perfume").glob("*.bvh")):
    yield ([f"perfume_{path.stem}"],
           lambda p=path: [sources.convert_bvh(p, sources.PERFUME_MAP, 0.01, "pop", "perfume", skel)])


def make_split(ids: list[str], data: pathlib.Path = sk.SHARED_DATA) -> dict:
  """Fixed split by song: ~20 % of the Tang songs, at least one per style, validate; the rest train.
  AIST++ dances (when converted) follow the official cross-modal split: its test list validates."""
  # Waltz takes reuse motion clips (docs/data.md): these five waltzes share the fewest frames with the
  # others (4-23 % of frames within 1 cm of a frame elsewhere, against up to 57 %).
  validation = ["tang_DANCE_C_6", "tang_DANCE_R_4", "tang_DANCE_T_5_b", "tang_DANCE_W_3",
                "tang_DANCE_W_12", "tang_DANCE_W_24", "tang_DANCE_W_29", "tang_DANCE_W_4"]
  aist_test = data / "skeleton" / "crossmodal_test.txt"
  if aist_test.exists():
    validation += [f"aist_{n}" for n in aist_test.read_text().split() if f"aist_{n}" in ids]
  missing = [v for v in validation if v not in ids]
  if missing:
    raise RuntimeError(f"validation ids not converted: {missing}")
  return {"version": 2,
          "note": "Split by song (docs/data.md). Tang has one tango: its first 75 % (tang_DANCE_T_5_a) "
                  "trains and its last 25 % (tang_DANCE_T_5_b) validates. Waltzes in validation are those "
                  "sharing the fewest reused motion clips with the others. Salsa and Perfume (no audio) "
                  "train the VQ-VAE only.",
          "train": sorted(i for i in ids if i not in validation),
          "validation": validation}


def main(argv=None) -> int:
  ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
  ap.add_argument("--data", type=pathlib.Path, default=sk.SHARED_DATA)
  ap.add_argument("--cache", type=pathlib.Path, default=CACHE)
  ap.add_argument("--aistpp", type=pathlib.Path, default=None, help="AIST++ root (motions/, wavs/)")
  ap.add_argument("--force", action="store_true")
  ap.add_argument("--tang-sides", choices=sources.TANG_SIDES, default=sources.TANG_SIDES_DEFAULT,
                  help="which reading of the Tang dancer's sides (docs/data.md \"Left vs right\"); a cache of "
                       "the other reading is rewritten")
  args = ap.parse_args(argv)
  args.cache.mkdir(parents=True, exist_ok=True)
  skel = sk.load_skeleton(args.data / "skeleton" / "smpl24_skeleton.json")
  all_ids = []
  for ids, thunk in jobs(args.data, skel, args.tang_sides):
    all_ids += ids
    paths = [args.cache / f"{i}.npz" for i in ids]
    sides = args.tang_sides if ids[0].startswith("tang_") else None
    if not args.force and all(_fresh(p, sides) for p in paths):
      continue
    for i, p, m in zip(ids, paths, thunk()):
      _save(p, m)
      print(f"{i}: {m.positions.shape[0]} frames, {m.style}", flush=True)
  if args.aistpp is not None:
    ignore_file = args.data / "skeleton" / "ignore_list.txt"
    ignore = set(ignore_file.read_text().split()) if ignore_file.exists() else set()
    for i, m in aistpp.load_aistpp(args.aistpp, skel, ignore):
      all_ids.append(i)
      p = args.cache / f"{i}.npz"
      if args.force or not _fresh(p):
        _save(p, m)
  split = make_split(all_ids, args.data)
  old = json.loads(SPLIT_PATH.read_text()) if SPLIT_PATH.exists() else None
  if (old is None or old.get("version", 0) < split["version"] or
      set(old["train"]) | set(old["validation"]) != set(all_ids)):
    SPLIT_PATH.write_text(json.dumps(split, indent=1) + "\n")
    print(f"wrote {SPLIT_PATH}")
  print(f"{len(all_ids)} motions in {args.cache}")
  return 0


if __name__ == "__main__":
  sys.exit(main())
