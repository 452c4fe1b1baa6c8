"""The metric table of the product itself: dances from the C++ engine (`dance-generate`) on the validation
songs, against the real dances and the baselines (training.eval.evaluate), plus rendered strips.

    .venv/bin/python -m training.eval.engine_eval --model models/default.dncw --out-dir training/runs/X/engine
        [--seed 0] [--temperature 1] [--guidance W] [--top-p P] [--period-lock B] [--songs ID,ID --fill-from D0]

Writes <out-dir>/dances/<id>.json (dance-motion/v1 from dance-generate), metrics.md, metrics.json (the model's
row over the whole songs and over the real dances' spans, evaluate.on_real_spans; the real rows) and
strip_<id>.png / beats_<id>.png for the first two songs. With --songs, only those songs are generated and the
other validation songs' dances are read from D0/s<seed>/dances/ (an earlier suite's draw of the same seed;
training.eval.engine_suite --songs). Needs librosa's beat cache (the project .venv).
"""
from __future__ import annotations

import argparse
import json
import pathlib
import subprocess

import numpy as np

from training import train_data as td
from training.eval.engine_tempo import dance_generate_bin

REPO = pathlib.Path(__file__).resolve().parents[2]


def generate_song(model: str, mid: str, out: pathlib.Path, seed: int, temperature: float,
                  period_lock: float | None = None, style: str | None = None,
                  guidance: float | None = None, top_p: float | None = None) -> pathlib.Path:
  """dance-generate on the song of motion `mid`, in its own style unless `style` is given; guidance and
  top_p None = the model's defaults."""
  z = np.load(td.MOTION_CACHE / f"{mid}.npz")
  cmd = [str(dance_generate_bin()), "--audio", str(z["audio_path"]), "--out", str(out), "--model", model,
         "--seed", str(seed), "--style", style or str(z["style"]), "--temperature", str(temperature), "--quiet"]
  if guidance is not None:
    cmd += ["--guidance", str(guidance)]
  if top_p is not None:
    cmd += ["--top-p", str(top_p)]
  if period_lock is not None:  # None: the model's default
    cmd += ["--period-lock", str(period_lock)]
  proc = subprocess.run(cmd, capture_output=True, text=True)
  if proc.returncode != 0:
    raise RuntimeError(f"dance-generate failed on {mid}: {proc.stderr.strip()}")
  return out


def main(argv=None) -> None:
  from training.eval.evaluate import Dance, Evaluator, load_dance, markdown_table, on_real_spans
  from training.eval.metrics import joint_speed, motion_beats
  from training.eval.render import render_beats, render_strip
  ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  ap.add_argument("--model", default=str(REPO / "models" / "default.dncw"))
  ap.add_argument("--out-dir", required=True)
  ap.add_argument("--seed", type=int, default=0)
  ap.add_argument("--temperature", type=float, default=1.0)
  ap.add_argument("--guidance", type=float, default=None,
                  help="style guidance (dance-generate --guidance; default: the model's)")
  ap.add_argument("--top-p", type=float, default=None, help="dance-generate --top-p (default: the model's)")
  ap.add_argument("--period-lock", type=float, default=None,
                  help="dance-generate --period-lock (default: the model's; 0 = off)")
  ap.add_argument("--songs", default=None, help="comma-separated validation motion ids to generate (needs "
                  "--fill-from)")
  ap.add_argument("--fill-from", default=None, help="a suite directory whose s<seed>/dances/ hold the other songs")
  args = ap.parse_args(argv)
  ids = td.tang_ids(td.load_split()["validation"])
  songs = set(args.songs.split(",")) if args.songs else set(ids)
  if not songs <= set(ids):
    ap.error(f"--songs: not validation songs: {', '.join(sorted(songs - set(ids)))}")
  if (args.songs is None) != (args.fill_from is None):
    ap.error("--songs and --fill-from go together")
  td.ensure_motion_cache()  # the real dances' audio paths and styles (a fresh checkout has no cache yet)
  out = pathlib.Path(args.out_dir)
  (out / "dances").mkdir(parents=True, exist_ok=True)
  dances = []
  for mid in ids:
    z = np.load(td.MOTION_CACHE / f"{mid}.npz")
    if mid in songs:
      path = generate_song(args.model, mid, out / "dances" / f"{mid}.json", args.seed, args.temperature,
                           args.period_lock, guidance=args.guidance, top_p=args.top_p)
    else:
      path = pathlib.Path(args.fill_from) / f"s{args.seed}" / "dances" / f"{mid}.json"
      if not path.exists():
        ap.error(f"--fill-from: {path} does not exist")
    d = load_dance(path, audio=str(z["audio_path"]))  # audio_offset_s: the song time of the first frame
    dances.append(Dance(mid, d.positions, d.fps, d.audio_path, d.audio_offset_s, str(z["style"])))
  ev = Evaluator.default()
  rows = {"model (engine)": ev.evaluate(dances),
          # The same dances cut to the real dances' song spans: the real row's segments, song for song.
          "model (engine), real spans": ev.evaluate(on_real_spans(dances, ev.validation))}
  rows.update(ev.baselines())
  table = markdown_table(rows)
  (out / "metrics.md").write_text(table)
  (out / "metrics.json").write_text(json.dumps(rows, indent=1))
  print(table)
  for d in dances[:2] + [x for x in dances if x.name == "tang_DANCE_W_3"]:
    render_strip(d.positions, str(out / f"strip_{d.name}.png"), start_s=20.0)
    speed = joint_speed(d.positions, d.fps)
    render_beats(speed, motion_beats(d.positions, d.fps), d.beats(), str(out / f"beats_{d.name}.png"),
                 window_s=(20.0, 32.0), title=f"{d.name} (engine, seed {args.seed})")


if __name__ == "__main__":
  main()
