"""Training curves as PNG (VQ-VAE losses, sequence-model losses and the music-ablation gap).

    /usr/bin/python3 -m training.plots training/runs/default [--out docs/images] [--extra RUN:LABEL ...]
"""
from __future__ import annotations

import argparse
import json
import pathlib

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def plot_vq(run: pathlib.Path, out: pathlib.Path) -> None:
  fig, axes = plt.subplots(1, 2, figsize=(10, 3.5))
  for ax, part in zip(axes, ("upper", "lower")):
    p = run / f"vq_{part}_history.json"
    if not p.is_file():
      continue
    h = json.loads(p.read_text())
    it = [r["iter"] for r in h]
    for key in ("loss", "rec", "vel", "path", "commit"):
      if key in h[0]:
        ax.plot(it, [r[key] for r in h], label=key)
    ax.set_yscale("log")
    ax.set_title(f"VQ-VAE {part}")
    ax.set_xlabel("iteration")
    ax.legend(fontsize=7)
  fig.tight_layout()
  fig.savefig(out / "training_vq.png", dpi=90)
  plt.close(fig)


def _phases(runs: list[tuple[pathlib.Path, str]]) -> list[tuple[pathlib.Path, str, int]]:
  """(run, label, iteration offset): a run with a fixed-rate phase (<run>/pretrain, training.train) is
  drawn as that phase followed by its tempo-normalised phase."""
  out = []
  for run, label in runs:
    pre = run / "pretrain" / "seq_history.json"
    if pre.is_file():
      h = json.loads(pre.read_text())
      out.append((run / "pretrain", f"{label}: fixed-rate phase", 0))
      out.append((run, f"{label}: tempo-normalised phase", max(r["iter"] for r in h)))
    else:
      out.append((run, label, 0))
  return out


def plot_seq(runs: list[tuple[pathlib.Path, str]], out: pathlib.Path) -> None:
  fig, axes = plt.subplots(1, 2, figsize=(10, 3.5))
  phases = _phases(runs)
  main_run = _phases(runs[:1])[-1][0]  # its training loss and wrong-music loss are drawn too
  for run, label, offset in phases:
    p = run / "seq_history.json"
    if not p.is_file():
      continue
    h = [dict(r, iter=r["iter"] + offset) for r in json.loads(p.read_text())]
    tr = [r for r in h if "loss" in r]
    va = [r for r in h if "val_loss" in r]
    line, = axes[0].plot([r["iter"] for r in va], [r["val_loss"] for r in va], label=f"{label} val")
    if run == main_run:
      axes[0].plot([r["iter"] for r in tr], [r["loss"] for r in tr], alpha=0.3, color=line.get_color(),
                   label=f"{label} train (masked inputs)")
      axes[0].plot([r["iter"] for r in va], [r["val_loss_wrong_music"] for r in va], "--",
                   color=line.get_color(), label=f"{label} val, wrong music")
    axes[1].plot([r["iter"] for r in va], [r["music_gap"] for r in va], label=label)
  axes[0].set_title("sequence model: cross-entropy")
  axes[1].set_title("music-ablation gap (val loss wrong music - true music)")
  for ax in axes:
    ax.set_xlabel("iteration")
    ax.legend(fontsize=7)
  axes[1].axhline(0, color="k", lw=0.5)
  fig.tight_layout()
  fig.savefig(out / "training_seq.png", dpi=90)
  plt.close(fig)


def main() -> None:
  ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  ap.add_argument("run")
  ap.add_argument("--out", default="docs/images")
  ap.add_argument("--label", default="default")
  ap.add_argument("--extra", nargs="*", default=[], help="RUN_DIR:LABEL of ablation runs")
  args = ap.parse_args()
  plot_run(pathlib.Path(args.run), pathlib.Path(args.out), args.label,
           [(pathlib.Path(e.split(":")[0]), e.split(":")[1]) for e in args.extra])


def plot_run(run: pathlib.Path, out: pathlib.Path, label: str = "default",
             extra: list[tuple[pathlib.Path, str]] | None = None) -> None:
  out.mkdir(parents=True, exist_ok=True)
  plot_vq(run, out)
  plot_seq([(run, label)] + list(extra or []), out)


if __name__ == "__main__":
  main()
