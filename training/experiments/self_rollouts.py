"""Filtered self-training data: the sequence model's own free-running dances on its training songs, cut into
10-s segments, scored against the real dances of the song's style, the best kept as extra training clips.

    /usr/bin/python3 -m training.experiments.self_rollouts --model M.dncw --tokens RUN/tokens_train_warp_....pt \
        --out RUN/self_tokens.pt [--draws 8] [--keep 0.4] [--guidance 3] [--seed 0]

Why (docs/research-log.md, "Filtered self-training"): given the real history of an unheard song the model
continues it nearly as the real dancer (teacher-forced argmax FID at the VQ ceiling), but on its own history it
drifts. Its training only ever showed it real histories. Here it is shown its own histories, and the
continuations it is taught are its own draws too, but only the segments that look most like real dancing of
the style (one round of expert iteration, with a per-segment realism score as the reward).

Score of a segment (--reward style): its normalised kinetic and geometric features (the evaluator's,
training.eval.evaluate), the distance to the nearest real training segment of the same style, each part
divided by the root of its dimension and the two summed; --reward song: the same distance to the song's own
real dance over the same song time (the continuations that, from the model's own history, land where the real
dancer was). Per style, the segments scoring below the `keep` quantile of that style's draws
are kept; runs of consecutive kept segments of a draw become clips in the token format of
tokens.build_tokens (the song's music and PRE over those steps, the draw's codes), marked "own_draw", with
the id "self:<song>:<draw>:<first segment>". train.py --self-tokens adds them to the training clips.
"""
from __future__ import annotations

import argparse
import json

import numpy as np
import torch

from training.common import clips as td
from training.data import skeleton as sk
from training.data.sources import TANG_STYLES
from training.eval import features
from training.eval.evaluate import Evaluator, segment_table
from training.experiments.free_run import decode_codes, free_running_draws
from training.export import load_models

SEGMENT_STEPS = int(features.SEGMENT_SECONDS * 30) // 4  # 75 code steps per 10-s segment


def style_of_dance(name: str) -> int:
  """The style row of a Tang dance id (tang_DANCE_<C|R|T|W>_...)."""
  return td.style_index(TANG_STYLES[name.split("DANCE_")[1][0]])


class SegmentScorer:
  """Distance of a segment's features to the nearest real training segment of a style."""

  def __init__(self, ev: Evaluator):
    self.ev = ev
    styles = np.array([style_of_dance(r["dance"]) for r in ev.ref_rows])
    self.ref = {int(s): (ev.ref_k[styles == s], ev.ref_g[styles == s]) for s in np.unique(styles)}

  def features(self, dances) -> tuple[np.ndarray, np.ndarray]:
    """Normalised kinetic and geometric features of every 10-s segment of `dances`, in order."""
    t = segment_table(dances, beats_of=lambda d: np.zeros(0))
    return self.ev.norm_k.apply(t["kinetic"]), self.ev.norm_g.apply(t["geometric"])

  @staticmethod
  def distance(k, g, rk, rg) -> np.ndarray:
    """Distance between segments (..., D) and reference segments (broadcast), each part divided by the
    root of its dimension."""
    return (np.linalg.norm(k - rk, axis=-1) / np.sqrt(k.shape[-1]) +
            np.linalg.norm(g - rg, axis=-1) / np.sqrt(g.shape[-1]))

  def scores(self, dances, style: int) -> np.ndarray:
    """One score per 10-s segment of `dances` (in order), lower = nearer real dancing of the style."""
    k, g = self.features(dances)
    rk, rg = self.ref[style]
    return self.distance(k[:, None], g[:, None], rk[None], rg[None]).min(1)

  def scores_against(self, dances, real) -> np.ndarray:
    """One score per 10-s segment of `dances` (in order): the distance to the segment of the song's real
    dance `real` (a Dance on the same timeline) over the same song time."""
    k, g = self.features(dances)
    rk, rg = self.features([real])
    n = len(rk)
    if len(k) % n:
      raise ValueError(f"{len(k)} segments of draws against {n} of the real dance")
    idx = np.arange(len(k)) % n
    return self.distance(k, g, rk[idx], rg[idx])


def kept_runs(keep: np.ndarray) -> list[tuple[int, int]]:
  """[(first, last)] of the runs of consecutive True segments."""
  runs, start = [], None
  for i, k in enumerate(list(keep) + [False]):
    if k and start is None:
      start = i
    elif not k and start is not None:
      runs.append((start, i - 1))
      start = None
  return runs


def clip_of_run(t: dict, upper: np.ndarray, lower: np.ndarray, first: int, last: int, draw: int) -> dict:
  """Token clip of segments first..last of a draw: token steps first*75 .. (last+1)*75 (the step before the
  run's first drawn code is its context). upper/lower are the draw's codes of token steps 1..n."""
  a, b = first * SEGMENT_STEPS, (last + 1) * SEGMENT_STEPS
  u = np.concatenate([[t["upper"][0]], upper])[a:b + 1].astype(np.int64)
  lo = np.concatenate([[t["lower"][0]], lower])[a:b + 1].astype(np.int64)
  return {"id": f"self:{t['id']}:{draw}:{first}", "factor": t.get("factor", 1.0), "style": t["style"],
          "upper": u, "lower": lo, "music": np.asarray(t["music"][a:b + 1]), "pre": np.asarray(t["pre"][a:b + 1]),
          "mirror": False, "own_draw": True}


def main(argv=None) -> None:
  ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
  ap.add_argument("--model", required=True, help="the .dncw whose sequence model draws (and whose decoders decode)")
  ap.add_argument("--tokens", required=True, help="the training run's token cache (its factor-1 clips are used)")
  ap.add_argument("--out", required=True, help="where to write the kept clips (torch.save of a list)")
  ap.add_argument("--draws", type=int, default=8)
  ap.add_argument("--keep", type=float, default=0.4, help="per style, the share of the draws' segments kept")
  ap.add_argument("--guidance", type=float, default=3.0, help="style guidance of the draws (the engine's default)")
  ap.add_argument("--seed", type=int, default=0)
  ap.add_argument("--reward", choices=("style", "song"), default="style",
                  help="style: distance to the nearest real training segment of the style; song: distance to "
                       "the song's own real dance over the same song time (its real codes, decoded)")
  args = ap.parse_args(argv)
  if args.draws < 1:
    ap.error("--draws must be at least 1")
  if not 0.0 < args.keep <= 1.0:
    ap.error("--keep must be in (0, 1]")
  torch.set_grad_enabled(False)
  model, vqs, _ = load_models(args.model)
  toks = [t for t in torch.load(args.tokens) if t.get("factor", 1.0) == 1.0 and not t.get("mirror", False)]
  ev, skel = Evaluator.default(), sk.load_skeleton()
  scorer = SegmentScorer(ev)
  gen = torch.Generator().manual_seed(args.seed)
  songs = []  # per song: draws' codes, segment scores (draws, segments), the real codes' segment scores
  for t in toks:
    gu, gl = free_running_draws(model, t, args.draws, gen, args.guidance)
    dances = [decode_codes(vqs, gu[i], gl[i], t["id"], skel) for i in range(args.draws)]
    n_seg = len(features.segments(dances[0].positions))
    real = decode_codes(vqs, np.asarray(t["upper"][1:]), np.asarray(t["lower"][1:]), t["id"], skel)
    if args.reward == "song":
      s = scorer.scores_against(dances, real).reshape(args.draws, n_seg)
    else:
      s = scorer.scores(dances, t["style"]).reshape(args.draws, n_seg)
    r = scorer.scores([real], t["style"])  # (the real codes by the style reward, for the report)
    songs.append({"t": t, "u": gu, "l": gl, "s": s, "real": r})
    print(f"{t['id']:<18} draws {s.mean():.3f} (best draw {s.mean(1).min():.3f})  real codes (style reward) "
          f"{r.mean():.3f}", flush=True)
  out, report = [], {}
  for style in sorted({x["t"]["style"] for x in songs}):
    mine = [x for x in songs if x["t"]["style"] == style]
    threshold = float(np.quantile(np.concatenate([x["s"].ravel() for x in mine]), args.keep))
    kept = 0
    for x in mine:
      for d in range(args.draws):
        for first, last in kept_runs(x["s"][d] <= threshold):
          out.append(clip_of_run(x["t"], x["u"][d], x["l"][d], first, last, d))
          kept += last - first + 1
    name = td.ALL_STYLES[style]
    report[name] = {"threshold": threshold, "segments_kept": kept,
                    "segments": int(sum(x["s"].size for x in mine)),
                    "draws_mean": float(np.mean([x["s"].mean() for x in mine])),
                    "real_codes_mean": float(np.mean([x["real"].mean() for x in mine]))}
    print(f"{name:<8} threshold {threshold:.3f}: {kept} of {report[name]['segments']} segments kept; "
          f"mean score draws {report[name]['draws_mean']:.3f}, real codes (style reward) "
          f"{report[name]['real_codes_mean']:.3f}")
  torch.save(out, args.out)
  steps = sum(len(c["upper"]) for c in out)
  print(f"self_rollouts: {len(out)} clips, {steps} steps -> {args.out}")
  print(json.dumps(report))


if __name__ == "__main__":
  main()
