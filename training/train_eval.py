"""Generation with the torch model (the engine's streaming semantics) and the evaluation of a trained run:
validation loss and music-ablation gap, tempo following on time-stretched validation songs, the metric
table of training/eval against the real dances, and rendered strips.

    generate_positions(model, vqs, audio_path, seed=0)  -> (T, 24, 3) positions at 30 fps
"""
from __future__ import annotations

import json
import pathlib

import numpy as np
import torch

from training import train_data as td
from training.data import representation as rep
from training.data.skeleton import load_skeleton, project_bone_lengths
from training.features.extract import extract_features
from training.model.danceba import Danceba

SKEL = load_skeleton()


@torch.no_grad()
def generate_codes(model: Danceba, features: np.ndarray, pre: np.ndarray, style: int, seeds, temperature=1.0,
                   top_k=0, max_steps: int | None = None) -> tuple[np.ndarray, np.ndarray]:
  """Streams the model from BOS over the music: (B, N) upper and lower codes of periods 1..N."""
  cfg = model.cfg
  n = len(features) // 4
  music = torch.from_numpy(features[:4 * n].reshape(n, -1))
  pre_t = torch.from_numpy(pre[:4 * n][3::4])
  s = cfg.music_lookahead_steps
  steps = n - s if max_steps is None else min(n - s, max_steps)
  b = len(seeds)
  gens = [torch.Generator().manual_seed(int(sd)) for sd in seeds]
  w = torch.zeros(b, cfg.n_styles + 1)
  w[:, cfg.n_styles if style < 0 else style] = 1
  u = torch.full((b,), cfg.codebook_size, dtype=torch.long)
  l = u.clone()
  state, out_u, out_l = None, [], []
  for t in range(steps):
    lu, ll, state = model.step(music[t + s].expand(b, -1), pre_t[t + s].expand(b, -1), u, l, w, state)
    picks = []
    for logits in (lu, ll):
      if temperature <= 0:
        picks.append(logits.argmax(-1))
        continue
      lg = logits / temperature
      if top_k:
        kth = torch.topk(lg, top_k, dim=-1).values[:, -1:]
        lg = lg.masked_fill(lg < kth, float("-inf"))
      p = torch.softmax(lg, -1)
      picks.append(torch.stack([torch.multinomial(p[i], 1, generator=gens[i])[0] for i in range(b)]))
    u, l = picks
    out_u.append(u)
    out_l.append(l)
  return torch.stack(out_u, 1).numpy(), torch.stack(out_l, 1).numpy()


@torch.no_grad()
def decode_positions(vqs, codes_u: np.ndarray, codes_l: np.ndarray) -> np.ndarray:
  """(N,) codes -> (4N, 24, 3) positions: causal decode, root integration, bone projection."""
  up = vqs["upper"].denormalise(vqs["upper"].decode_codes(torch.from_numpy(codes_u)[None]))[0].numpy()
  lo = vqs["lower"].denormalise(vqs["lower"].decode_codes(torch.from_numpy(codes_l)[None]))[0].numpy()
  return project_bone_lengths(rep.decode(up, lo), SKEL)


def generate_positions(model, vqs, audio_path: str, seeds=(0,), style: int = -1, temperature=1.0,
                       top_k=0, max_steps=None) -> list[np.ndarray]:
  m = extract_features(audio_path, cache_dir=td.FEATURE_CACHE)
  cu, cl = generate_codes(model, m["features"], m["pre"], style, seeds, temperature, top_k, max_steps)
  return [decode_positions(vqs, cu[i], cl[i]) for i in range(len(seeds))]


def _style_of(motion_id: str) -> int:
  z = np.load(td.MOTION_CACHE / f"{motion_id}.npz")
  return td.style_index(str(z["style"]))


def tempo_report(model, vqs, ids, workdir: pathlib.Path, seeds=(0, 1), log=print, **sampling) -> dict:
  """Tempo-following ratio per validation song and seed (training.eval.tempo), first 60 s of each song."""
  from training.eval.tempo import tempo_following
  rows = []
  for mid in ids:
    audio = str(np.load(td.MOTION_CACHE / f"{mid}.npz")["audio_path"])
    style = _style_of(mid)
    for sd in seeds:
      gen = lambda path, sd=sd: generate_positions(model, vqs, path, (sd,), style, max_steps=450,  # noqa
                                                   **sampling)[0]
      r = tempo_following(gen, audio, workdir)
      r.update(id=mid, seed=sd)
      rows.append(r)
      log(f"tempo {mid} seed {sd}: ratio {r['ratio']:.2f} periods {r['base_period_s']:.2f} {r['periods_s']}")
  ratios = [r["ratio"] for r in rows if np.isfinite(r["ratio"])]
  return {"mean_ratio": float(np.mean(ratios)) if ratios else float("nan"), "rows": rows}


def evaluate_model(model, vqs, run: pathlib.Path, log, n_songs: int = 8) -> dict:
  from training.train_seq import build_tokens, validation
  split = td.load_split()
  val_ids = td.tang_ids(split["validation"])[:n_songs]
  val_toks = build_tokens(val_ids, (1.0,), vqs, log)
  report = {"losses": validation(model, val_toks, model.cfg, n_batches=12)}
  log(f"eval losses: {json.dumps(report['losses'])}")
  report["tempo"] = tempo_report(model, vqs, val_ids, run / "tempo", log=log)
  log(f"eval tempo-following mean ratio {report['tempo']['mean_ratio']:.3f}")
  try:
    report["metrics"] = metric_table(model, vqs, val_ids, run, log)
  except Exception as e:  # the metric table needs librosa (the .venv); report, do not fail the run
    log(f"eval metrics skipped: {e!r}")
  return report


def metric_table(model, vqs, ids, run: pathlib.Path, log) -> dict:
  from training.eval.evaluate import Dance, Evaluator, markdown_table
  from training.eval.render import render_strip
  dances = []
  for mid in ids:
    z = np.load(td.MOTION_CACHE / f"{mid}.npz")
    audio = str(z["audio_path"])
    pos = generate_positions(model, vqs, audio, (0,), _style_of(mid))[0]
    # Generated frames start at period 1 (frame 4) of the song's audio.
    dances.append(Dance(mid, pos, 30.0, audio, 4 / 30.0, str(z["style"])))
    out = {"format": "dance-motion/v1", "fps": 30, "units": "m", "up_axis": "y",
           "joint_names": list(SKEL.as_json()["joint_names"]), "positions": np.round(pos, 4).tolist(),
           "audio_offset_s": 4 / 30.0, "audio_path": audio}
    (run / "dances").mkdir(exist_ok=True)
    (run / "dances" / f"{mid}.json").write_text(json.dumps(out))
  ev = Evaluator.default()
  rows = {"model": ev.evaluate(dances)}
  rows.update(ev.baselines())
  table = markdown_table(rows)
  (run / "metrics.md").write_text(table)
  log("metrics:\n" + table)
  render_strip(dances[0].positions, str(run / "strip.png"), start_s=10.0)
  return rows
