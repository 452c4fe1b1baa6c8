"""Can the music alone tell the style, causally, within the first seconds? A feasibility screen for a
recogniser that picks the style when the user names none (issue 40 item 1; docs/research-log.md, "The
engine against the PyTorch model").

    /usr/bin/python3 -m training.experiments.style_recognizer [--tau 8] [--stride 15]

Per frame, the engine's causal features (`dance-features`: MFCC, chroma, onset strength, RMS, the
tempogram, the running tempo and the beat confidence; not the beat and bar phases) averaged causally with an
exponential window of --tau seconds (the state a session would carry: one vector); the tempo as log2 folded
into one octave, sin and cos (a waltz tracked at the eighth-note level is the same tempo class). A linear
classifier (shrinkage LDA, equal priors: training.experiments.style_probe's) fitted on the 31 Tang training
songs' frames from 2 s on (every --stride frames), tested on the 8 validation songs: the share of frames
whose style is right at 2, 4, 8, 15 and 30 s into the song and over every frame, per song. Caveat: one
recording session per style, so the classifier may learn the songs' production as much as the style.
"""
from __future__ import annotations

import argparse

import numpy as np

from training.common import clips as td
from training.features.extract import extract_features

FEATURES = list(range(0, 20)) + list(range(40, 54)) + list(range(54, 102)) + [107]
TEMPO = 104
STYLES = ["cha-cha", "rumba", "tango", "waltz"]


def song_of(mid: str) -> tuple[str, str]:
  z = np.load(td.MOTION_CACHE / f"{mid}.npz")
  return str(z["audio_path"]), str(z["style"])


def causal_state(features: np.ndarray, tau_frames: float) -> np.ndarray:
  """(T, D) the exponential moving average of the chosen columns plus the folded tempo, frame by frame."""
  t = features[:, TEMPO].astype(np.float64)  # log2(tempo / 120)
  octave = 2 * np.pi * np.mod(t, 1.0)
  x = np.concatenate([features[:, FEATURES].astype(np.float64), np.sin(octave)[:, None], np.cos(octave)[:, None]], 1)
  a = 1.0 / tau_frames
  out = np.empty_like(x)
  s = x[0].copy()
  out[0] = s
  for i in range(1, len(x)):
    s += a * (x[i] - s)
    out[i] = s
  return out


def fit_lda(x: np.ndarray, y: np.ndarray, n: int, shrink: float = 0.2):
  """Shrinkage LDA with equal priors: (W (n, D), b (n,), mean (D,), std (D,))."""
  mu, sd = x.mean(0), x.std(0) + 1e-6
  z = (x - mu) / sd
  means = np.stack([z[y == c].mean(0) for c in range(n)])
  cov = sum(np.cov((z[y == c] - means[c]).T) for c in range(n)) / n
  cov = (1 - shrink) * cov + shrink * np.eye(len(cov)) * np.trace(cov) / len(cov)
  w = np.linalg.solve(cov, means.T).T
  b = -0.5 * (w * means).sum(1)
  return w, b, mu, sd


def main(argv=None) -> None:
  ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
  ap.add_argument("--tau", type=float, default=8.0, help="the causal average's time constant, s")
  ap.add_argument("--stride", type=int, default=15, help="training frames: every N-th")
  args = ap.parse_args(argv)
  td.ensure_motion_cache()
  split = td.load_split()
  train = [m for m in td.tang_ids(split["train"]) if not m.endswith("_a")] + ["tang_DANCE_T_5_a"]
  val = [m for m in td.tang_ids(split["validation"]) if m != "tang_DANCE_T_5_b"]  # T_5's song trains
  states = {}
  for mid in sorted(set(train + val)):
    audio, style = song_of(mid)
    f = extract_features(audio, cache_dir=td.FEATURE_CACHE)["features"]
    states[mid] = (causal_state(f, args.tau * 30), STYLES.index(style))
  xs, ys = [], []
  for mid in train:
    s, c = states[mid]
    xs.append(s[60::args.stride])
    ys.append(np.full(len(xs[-1]), c))
  w, b, mu, sd = fit_lda(np.concatenate(xs), np.concatenate(ys), len(STYLES))
  print(f"train songs {len(train)}, validation songs {len(val)} (the tango's song trains), tau {args.tau} s")
  marks = (2, 4, 8, 15, 30)
  print("song               style     " + "  ".join(f"{m:>3d} s" for m in marks) + "   all frames")
  hits = {m: [] for m in marks}
  for mid in val:
    s, c = states[mid]
    pred = np.argmax(((s - mu) / sd) @ w.T + b, 1)
    row = []
    for m in marks:
      ok = bool(pred[min(m * 30, len(pred) - 1)] == c)
      hits[m].append(ok)
      row.append("  ok " if ok else STYLES[pred[min(m * 30, len(pred) - 1)]][:5])
    print(f"{mid:<18} {STYLES[c]:<8} " + "  ".join(row) + f"   {np.mean(pred[60:] == c):.2f}")
  print("right at " + ", ".join(f"{m} s: {np.mean(hits[m]):.2f}" for m in marks))


if __name__ == "__main__":
  main()
