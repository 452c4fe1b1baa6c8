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

import numpy as np

from training import tools
from training.common import clips as td
from training.eval import evaluate, metrics, render

REPO = pathlib.Path(__file__).resolve().parents[2]


def generate_song(model: str, mid: str, out: pathlib.Path, seed: int, temperature: float,
                  period_lock: float | None = None, style: str | None = None,
                  guidance: float | None = None, top_p: float | None = None) -> pathlib.Path:
  """dance-generate on the song of motion `mid`, in its own style unless `style` is given; guidance and
  top_p None = the model's defaults."""
  z = np.load(td.MOTION_CACHE / f"{mid}.npz")
  return tools.dance_generate(model, str(z["audio_path"]), out, seed=seed, temperature=temperature,
                              style=style or str(z["style"]), top_p=top_p, guidance=guidance,
                              period_lock=period_lock)


def evaluate_model(model: str, out_dir, seed: int = 0, temperature: float = 1.0, guidance: float | None = None,
                   top_p: float | None = None, period_lock: float | None = None, songs: set[str] | None = None,
                   fill_from=None) -> dict:
  """The metric table of `model`'s engine dances (module docstring), written into out_dir; returns its rows.
  songs: the validation songs to generate (default: all), the others read from fill_from's draw of `seed`."""
  ids = td.tang_ids(td.load_split()["validation"])
  songs = set(ids) if songs is None else songs
  td.ensure_motion_cache()  # the real dances' audio paths and styles (a fresh checkout has no cache yet)
  out = pathlib.Path(out_dir)
  (out / "dances").mkdir(parents=True, exist_ok=True)
  dances = []
  for mid in ids:
    z = np.load(td.MOTION_CACHE / f"{mid}.npz")
    if mid in songs:
      path = generate_song(model, mid, out / "dances" / f"{mid}.json", seed, temperature, period_lock,
                           guidance=guidance, top_p=top_p)
    else:
      path = pathlib.Path(fill_from) / f"s{seed}" / "dances" / f"{mid}.json"
    d = evaluate.load_dance(path, audio=str(z["audio_path"]))  # audio_offset_s: the song time of the first frame
    dances.append(evaluate.Dance(mid, d.positions, d.fps, d.audio_path, d.audio_offset_s, str(z["style"])))
  ev = evaluate.Evaluator.default()
  rows = {"model (engine)": ev.evaluate(dances),
          # The same dances cut to the real dances' song spans: the real row's segments, song for song.
          "model (engine), real spans": ev.evaluate(evaluate.on_real_spans(dances, ev.validation))}
  rows.update(ev.baselines())
  table = evaluate.markdown_table(rows)
  (out / "metrics.md").write_text(table)
  (out / "metrics.json").write_text(json.dumps(rows, indent=1))
  print(table)
  for d in dances[:2] + [x for x in dances if x.name == "tang_DANCE_W_3"]:
    render.render_strip(d.positions, str(out / f"strip_{d.name}.png"), start_s=20.0)
    speed = metrics.joint_speed(d.positions, d.fps)
    render.render_beats(speed, metrics.motion_beats(d.positions, d.fps), d.beats(), str(out / f"beats_{d.name}.png"),
                        window_s=(20.0, 32.0), title=f"{d.name} (engine, seed {seed})")
  return rows


def main(argv=None) -> None:
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
  for mid in sorted(set(ids) - songs):
    path = pathlib.Path(args.fill_from) / f"s{args.seed}" / "dances" / f"{mid}.json"
    if not path.exists():
      ap.error(f"--fill-from: {path} does not exist")
  evaluate_model(args.model, args.out_dir, args.seed, args.temperature, args.guidance, args.top_p,
                 args.period_lock, songs, args.fill_from)


if __name__ == "__main__":
  main()
