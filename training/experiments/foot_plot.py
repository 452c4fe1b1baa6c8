"""The foot lock, seen: one foot joint's horizontal speed, its height and its path from above, for the same
song and seed generated with the foot lock and without (dance-generate --foot-lock 1 / 0, or two suites'
dances), beside the real dancer's speed on that song.

Usage (from the repository root):
  /usr/bin/python3 -m training.experiments.foot_plot --on D_ON/tang_DANCE_R_4.json --off D_OFF/tang_DANCE_R_4.json \
      --song tang_DANCE_R_4 --start 20 --out docs/images/foot_lock_R_4.png
"""
from __future__ import annotations

import argparse

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from training.common import clips as td  # noqa: E402
from training.data import skeleton as sk  # noqa: E402
from training.eval.evaluate import load_dance  # noqa: E402

FPS = 30.0


def horizontal_speed(positions: np.ndarray, joint: int) -> np.ndarray:
  return np.linalg.norm(np.gradient(positions[:, joint, [0, 2]], axis=0), axis=-1) * FPS


def main(argv=None) -> None:
  ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
  ap.add_argument("--on", required=True, help="dance-motion/v1 JSON, foot lock on")
  ap.add_argument("--off", required=True, help="the same song and seed, foot lock off")
  ap.add_argument("--song", required=True, help="validation motion id (for the real dancer)")
  ap.add_argument("--start", type=float, default=20.0, help="seconds")
  ap.add_argument("--seconds", type=float, default=8.0)
  ap.add_argument("--joint", default="left_foot")
  ap.add_argument("--out", required=True)
  args = ap.parse_args(argv)
  z = np.load(td.MOTION_CACHE / f"{args.song}.npz")
  on = load_dance(args.on, audio=str(z["audio_path"])).positions
  off = load_dance(args.off, audio=str(z["audio_path"])).positions
  real = z["positions"]
  j = sk.JOINT_NAMES.index(args.joint)
  a, b = int(args.start * FPS), int((args.start + args.seconds) * FPS)
  t = np.arange(a, b) / FPS
  fig = plt.figure(figsize=(12, 8))
  speed = fig.add_subplot(3, 1, 1)
  height = fig.add_subplot(3, 1, 2, sharex=speed)
  path = fig.add_subplot(3, 1, 3)
  for name, p, c in (("decoded (foot lock off)", off, "tab:red"), ("foot lock on", on, "tab:blue")):
    speed.plot(t, horizontal_speed(p, j)[a:b], c, label=name, lw=1)
    height.plot(t, p[a:b, j, 1] * 100, c, lw=1)
    path.plot(p[a:b, j, 0], p[a:b, j, 2], c, lw=1)
  speed.plot(t, horizontal_speed(real, j)[a:b], "k", lw=0.8, alpha=0.5, label="real dancer (same song)")
  speed.set_ylabel(f"{args.joint}\nhorizontal speed (m/s)")
  speed.set_ylim(0, 3)
  speed.legend(loc="upper right", fontsize=8)
  for h in (3, 10):  # the lock's full and zero contact heights (engine/vq/foot_lock.h)
    height.axhline(h, color="gray", ls=":")
  height.set_ylabel(f"{args.joint}\nheight (cm)")
  height.set_xlabel("time (s)")
  path.set_xlabel(f"the {args.joint} joint's path seen from above: x (m)")
  path.set_ylabel("z (m)")
  path.set_aspect("equal", adjustable="datalim")
  fig.suptitle(f"{args.song}: the foot lock ({args.seconds:.0f} s from {args.start:.0f} s)")
  fig.tight_layout()
  fig.savefig(args.out, dpi=90)


if __name__ == "__main__":
  main()
