"""Style probe: does a dance look like the style it was asked for?

A linear classifier (shrinkage LDA, closed form, equal class priors) is fitted on 10-second segments of
the real Tang training dances (cha-cha, rumba, tango, waltz) and scores any set of dances: the fraction of
segments it assigns to the dance's intended style. Its accuracy on the real validation dances (other songs,
other takes) says what the probe can tell apart; a generated set scoring far below that has weak style.

Descriptor per segment (DESCRIPTOR_DIMS): body-frame joint positions (pelvis at the origin horizontally,
facing +Z; features._local) averaged over the segment and their standard deviation (posture and its range:
arms in a hold or raised, stance width), log kinetic energies (features.kinetic_features), and the
geometric relation fractions (features.geometric_features).

  .venv/bin/python -m training.experiments.style_probe --dances DIR [DIR ...]     # dance-motion/v1 files
  .venv/bin/python -m training.experiments.style_probe --prompts --model models/default.dncw --seed 0 \
      --out-dir training/runs/X/prompts [--guidance W] [--temperature T]

--prompts generates every validation song once per Tang style (dance-generate --style NAME) and prints the
confusion matrix of prompted style against the probe's call: style control, independent of the music.
"""
from __future__ import annotations

import argparse
import json
import pathlib

import numpy as np

from training.common import clips as td
from training.eval import features
from training.eval.engine_eval import generate_song
from training.eval.evaluate import cached_dances, load_dance, split_ids

STYLES = ("cha-cha", "rumba", "tango", "waltz")
REPO = pathlib.Path(__file__).resolve().parents[2]


def descriptor(seg: np.ndarray, fps: float = 30.0) -> np.ndarray:
  loc = features._local(seg)[:, 1:]                 # (T, 23, 3): the pelvis is the origin
  posture = np.concatenate([loc.mean(0).reshape(-1), loc.std(0).reshape(-1)])
  kin = np.log(features.kinetic_features(seg, fps) + 1e-4)
  geo = features.geometric_features(seg, fps)
  return np.concatenate([posture, kin, geo])


DESCRIPTOR_DIMS = 23 * 3 * 2 + 72 + len(features.GEOMETRIC_NAMES)


class StyleProbe:
  """Shrinkage LDA: w_c = S^-1 mu_c, b_c = -mu_c' S^-1 mu_c / 2 with S the pooled within-class
  covariance shrunk toward its diagonal; inputs standardised with the training statistics."""

  def __init__(self, x: np.ndarray, y: list[str], shrink: float = 0.5):
    self.classes = sorted(set(y))
    if len(self.classes) < 2:
      raise ValueError("style probe: need at least two styles to tell apart")
    y = np.asarray(y)
    self.mean = x.mean(0)
    self.scale = x.std(0) + 1e-6
    z = (x - self.mean) / self.scale
    mus = np.stack([z[y == c].mean(0) for c in self.classes])
    within = np.concatenate([z[y == c] - mus[i] for i, c in enumerate(self.classes)])
    s = np.cov(within, rowvar=False)
    s = (1 - shrink) * s + shrink * np.diag(np.diag(s)) + 1e-3 * np.eye(len(s))
    self.w = np.linalg.solve(s, mus.T)                                  # (D, C)
    self.b = -0.5 * np.einsum("cd,dc->c", mus, self.w)

  def predict(self, x: np.ndarray) -> list[str]:
    z = (np.atleast_2d(x) - self.mean) / self.scale
    return [self.classes[i] for i in np.argmax(z @ self.w + self.b, axis=1)]


def dance_segments(dances) -> tuple[np.ndarray, list[str], list[str]]:
  """Descriptors of every full 10-s segment, the dance's style per segment and the dance's name."""
  xs, ys, names = [], [], []
  for d in dances:
    for seg in features.segments(d.positions, d.fps):
      xs.append(descriptor(seg, d.fps))
      ys.append(d.style)
      names.append(d.name)
  return np.array(xs).reshape(-1, DESCRIPTOR_DIMS), ys, names


def confusion(truth: list[str], pred: list[str], classes=STYLES) -> np.ndarray:
  m = np.zeros((len(classes), len(classes)), dtype=int)
  for t, p in zip(truth, pred):
    if t in classes and p in classes:
      m[classes.index(t), classes.index(p)] += 1
  return m


def report(name: str, truth: list[str], pred: list[str]) -> dict:
  m = confusion(truth, pred)
  per = {c: float(m[i, i] / m[i].sum()) for i, c in enumerate(STYLES) if m[i].sum()}
  acc = float(np.trace(m) / max(m.sum(), 1))
  bal = float(np.mean(list(per.values()))) if per else float("nan")
  lines = [f"{name}: accuracy {acc:.3f}, balanced {bal:.3f} ({m.sum()} segments)",
           "  intended \\ called  " + " ".join(f"{c:>8}" for c in STYLES)]
  lines += [f"  {c:>18}  " + " ".join(f"{v:8d}" for v in m[i]) for i, c in enumerate(STYLES)]
  print("\n".join(lines))
  return {"accuracy": acc, "balanced": bal, "per_style": per, "confusion": m.tolist(), "segments": int(m.sum())}


def default_probe():
  train = [d for d in cached_dances(split_ids("train")) if d.style in STYLES]
  x, y, _ = dance_segments(train)
  return StyleProbe(x, y)


def main(argv=None) -> None:
  ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  ap.add_argument("--dances", nargs="*", default=[], help="directories of dance-motion/v1 files")
  ap.add_argument("--prompts", action="store_true", help="generate each validation song in each style")
  ap.add_argument("--model", default=str(REPO / "models" / "default.dncw"))
  ap.add_argument("--seed", type=int, default=0)
  ap.add_argument("--temperature", type=float, default=1.0)
  ap.add_argument("--guidance", type=float, default=None, help="default: the model's")
  ap.add_argument("--top-p", type=float, default=None, help="default: the model's")
  ap.add_argument("--out-dir", default=None, help="--prompts: where the dances and probe.json go")
  args = ap.parse_args(argv)
  probe = default_probe()
  results = {}
  val = [d for d in cached_dances(split_ids("validation")) if d.style in STYLES]
  x, y, _ = dance_segments(val)
  results["real (validation)"] = report("real validation dances", y, probe.predict(x))
  for d in args.dances:
    ds = [load_dance(p) for p in sorted(pathlib.Path(d).glob("*.json"))]
    for dance in ds:  # dance-generate writes the prompt as {name: weight}; the heaviest one is intended
      if isinstance(dance.style, dict) and dance.style:
        dance.style = max(dance.style, key=dance.style.get)
      if dance.style not in STYLES:  # no prompt recorded: the song's own style
        dance.style = str(np.load(td.MOTION_CACHE / f"{dance.name.split('__')[0]}.npz")["style"])
    x, y, _ = dance_segments(ds)
    results[d] = report(d, y, probe.predict(x))
  if args.prompts:
    if not args.out_dir:
      ap.error("--prompts needs --out-dir")
    out = pathlib.Path(args.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ds = []
    for d in val:
      audio = str(np.load(td.MOTION_CACHE / f"{d.name}.npz")["audio_path"])
      for style in STYLES:
        path = out / f"{d.name}__{style}.json"
        generate_song(args.model, d.name, path, args.seed, args.temperature, style=style,
                      guidance=args.guidance, top_p=args.top_p)
        g = load_dance(path, audio=audio)
        g.style = style
        ds.append(g)
    x, y, _ = dance_segments(ds)
    results["prompted"] = report(f"prompted styles (guidance {args.guidance or 'default'}, top_p "
                                 f"{args.top_p or 'default'}, temperature {args.temperature}, seed {args.seed})",
                                 y, probe.predict(x))
    (out / "probe.json").write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
  main()
