"""Which side of the Tang dancer is which: every cue of the raw capture, per take (docs/data.md "Left vs
right").

    /usr/bin/python3 -m training.experiments.tang_sides [--data ../shared/data] [--out docs/images]

Works on the raw 23 points (tang2018/*/motion.npz, cm, 25 fps), before any conversion, in the body frame of
the current reading (lateral axis toward the 12-20 side, called side A; side B is 3-11; forward = across x
up, which puts the toes ahead of the heels with either labelling only if the coordinates are taken as they
are for A = left, or mirrored for A = right). The cues do not depend on that choice: each is measured
against the extended arm of the hold (side A in the standard dances), so it reads the same in a mirror.
Per take (median over frames):
- arms: each wrist's offset from its shoulder (lateral, up, forward);
- head: the head's offset from the shoulders' midpoint, and the yaw and roll of the line between the two
  head points (0 -> 1, 11 cm apart, a left and a right head marker: level and sideways in the Latin takes):
  positive = the face turned toward side B, the side-B ear lower;
- trunk: the shoulders' midpoint against the hips' midpoint (lateral, forward);
- feet: heel point minus toe point height in stance (both low, the toe slow).
Prints a table per style and writes `tang_sides.png` (the cues per take) and `tang_sides_pose.png` (a waltz
frame from the front, the side and above).
"""
from __future__ import annotations

import argparse
import pathlib

import numpy as np

REPO = pathlib.Path(__file__).resolve().parents[2]
P = dict(head_a=0, head_b=1, spine=2, b_sh=3, b_el=4, b_wr=6, b_hip=7, b_kn=8, b_an=9, b_heel=10, b_toe=11,
         a_sh=12, a_el=13, a_wr=15, a_hip=16, a_kn=17, a_an=18, a_heel=19, a_toe=20)
BONES = [("a_sh", "a_el"), ("a_el", "a_wr"), ("b_sh", "b_el"), ("b_el", "b_wr"), ("a_sh", "b_sh"),
         ("a_hip", "b_hip"), ("a_hip", "a_kn"), ("a_kn", "a_an"), ("a_an", "a_heel"), ("a_heel", "a_toe"),
         ("a_an", "a_toe"), ("b_hip", "b_kn"), ("b_kn", "b_an"), ("b_an", "b_heel"), ("b_heel", "b_toe"),
         ("b_an", "b_toe"), ("head_a", "head_b")]


def body_frame(p: dict) -> tuple[np.ndarray, np.ndarray]:
  """Per frame (T, 3) unit lateral (toward side A) and forward axes of the current reading."""
  across = (p["a_hip"] - p["b_hip"]) + (p["a_sh"] - p["b_sh"])
  across[:, 1] = 0
  across /= np.linalg.norm(across, axis=1, keepdims=True)
  return across, np.cross(across, np.array([0.0, 1.0, 0.0]))


def take_cues(folder: pathlib.Path) -> dict[str, float]:
  z = np.load(folder / "motion.npz")
  g = z["skeletons"].astype(np.float64) + z["center"][:, None].astype(np.float64)  # cm, global
  p = {k: g[:, i] for k, i in P.items()}
  lat, fwd = body_frame(p)

  def body(v):  # (lateral toward A, up, forward)
    return np.stack([(v * lat).sum(1), v[:, 1], (v * fwd).sum(1)], 1)

  sh = 0.5 * (p["a_sh"] + p["b_sh"])
  hips = 0.5 * (p["a_hip"] + p["b_hip"])
  head = 0.5 * (p["head_a"] + p["head_b"])
  ab = body(p["head_b"] - p["head_a"])  # toward side A in the Latin takes
  out = {}
  for side in "ab":
    w = np.median(body(p[f"{side}_wr"] - p[f"{side}_sh"]), 0)
    out[f"{side}_wrist_out"], out[f"{side}_wrist_up"], out[f"{side}_wrist_fwd"] = abs(w[0]), w[1], w[2]
  h = np.median(body(head - sh), 0)
  out["head_to_b"], out["head_fwd"] = -h[0], h[2]
  out["head_yaw_to_b"] = float(np.degrees(np.median(np.arctan2(ab[:, 2], ab[:, 0]))))
  out["head_roll_to_b"] = float(np.degrees(np.median(np.arctan2(ab[:, 1], np.hypot(ab[:, 0], ab[:, 2])))))
  t = np.median(body(sh - hips), 0)
  out["trunk_to_b"], out["trunk_fwd"] = -t[0], t[2]
  floor = np.percentile(np.minimum(p["a_toe"][:, 1], p["b_toe"][:, 1]), 2)
  rise = []
  for side in "ab":
    heel, toe = p[f"{side}_heel"], p[f"{side}_toe"]
    speed = np.r_[0.0, np.linalg.norm(np.diff(toe[:, [0, 2]], axis=0), axis=1) * 25.0]
    stance = (np.minimum(heel[:, 1], toe[:, 1]) < floor + 3.0) & (speed < 15.0)
    rise.append(heel[stance, 1] - toe[stance, 1])
  out["heel_above_toe"] = float(np.median(np.concatenate(rise)))
  return out


CUES = [("head_yaw_to_b", "head yaw toward B (deg)"), ("head_roll_to_b", "head roll, B ear down (deg)"),
        ("head_to_b", "head toward B (cm)"), ("head_fwd", "head forward of shoulders (cm)"),
        ("trunk_to_b", "shoulders toward B (cm)"), ("trunk_fwd", "shoulders forward of hips (cm)"),
        ("a_wrist_out", "A wrist out from shoulder (cm)"), ("b_wrist_out", "B wrist out (cm)"),
        ("a_wrist_up", "A wrist above shoulder (cm)"), ("b_wrist_up", "B wrist above shoulder (cm)"),
        ("b_wrist_fwd", "B wrist forward (cm)"), ("heel_above_toe", "heel above toe in stance (cm)")]


def plot_cues(rows: list[tuple[str, dict]], out: pathlib.Path) -> None:
  import matplotlib
  matplotlib.use("Agg")
  import matplotlib.pyplot as plt
  colours = {"C": "tab:orange", "R": "tab:red", "T": "tab:purple", "W": "tab:blue"}
  fig, axes = plt.subplots(3, 4, figsize=(15, 9))
  for ax, (key, label) in zip(axes.flat, CUES):
    for i, (name, c) in enumerate(rows):
      st = name.split("_")[1]
      ax.scatter(i, c[key], color=colours[st], s=14)
    ax.axhline(0, color="k", lw=0.5)
    ax.set_title(label, fontsize=9)
    ax.set_xticks([])
  for st, col in colours.items():
    axes[0, 0].scatter([], [], color=col, label={"C": "cha-cha", "R": "rumba", "T": "tango", "W": "waltz"}[st])
  axes[0, 0].legend(fontsize=7)
  fig.suptitle("Tang 2018, raw points, per take (x: takes C, R, T, W). Side A = points 12-20 (the extended arm "
               "in the standard hold), B = 3-11")
  fig.tight_layout()
  fig.savefig(out, dpi=80)
  plt.close(fig)


def plot_pose(folder: pathlib.Path, frame: int, out: pathlib.Path) -> None:
  """One frame from three views; frame < 0: the take's most typical frame (see below)."""
  import matplotlib
  matplotlib.use("Agg")
  import matplotlib.pyplot as plt
  z = np.load(folder / "motion.npz")
  g = z["skeletons"].astype(np.float64) + z["center"][:, None].astype(np.float64)
  p = {k: g[:, i] for k, i in P.items()}
  lat, fwd = body_frame(p)
  if frame < 0:  # the frame whose head line and wrists lie closest to the take's medians: a typical one
    feats = []
    for a, b in (("head_a", "head_b"), ("a_sh", "a_wr"), ("b_sh", "b_wr")):
      v = p[b] - p[a]
      feats.append(np.stack([(v * lat).sum(1), v[:, 1], (v * fwd).sum(1)], 1))
    f = np.concatenate(feats, 1)
    frame = int(np.argmin(np.linalg.norm(f - np.median(f, 0), axis=1)))
  c = 0.5 * (p["a_hip"][frame] + p["b_hip"][frame])
  q = {k: np.array([((v[frame] - c) * lat[frame]).sum(), v[frame, 1] - c[1], ((v[frame] - c) * fwd[frame]).sum()])
       for k, v in p.items()}
  fig, axes = plt.subplots(1, 3, figsize=(14, 5.5))
  views = [("front (we face the dancer: side A on our right)", 0, 1, 1), ("side (forward to the right)", 2, 1, 1),
           ("above (forward up)", 0, 2, -1)]
  for ax, (title, i, j, flip) in zip(axes, views):
    for a, b in BONES:
      col = "tab:red" if a.startswith("a_") or b.startswith("a_") else "tab:blue"
      if a.startswith("head"):
        col = "k"
      ax.plot([flip * q[a][i], flip * q[b][i]] if i != 2 else [q[a][i], q[b][i]], [q[a][j], q[b][j]], color=col, lw=2)
    for k in ("head_a", "head_b"):
      ax.scatter(flip * q[k][i] if i != 2 else q[k][i], q[k][j], color="k", s=20)
    ax.annotate("head pt 1", (flip * q["head_b"][i] if i != 2 else q["head_b"][i], q["head_b"][j]), fontsize=8)
    ax.set_aspect("equal")
    ax.set_title(title, fontsize=9)
    ax.grid(alpha=0.3)
  fig.suptitle(f"{folder.name} frame {frame}, raw points in the body frame (cm): red = side A (12-20, extended "
               f"arm), blue = side B (3-11)")
  fig.tight_layout()
  fig.savefig(out, dpi=80)
  plt.close(fig)


def main(argv=None) -> None:
  ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
  ap.add_argument("--data", default=str(REPO.parent / "shared" / "data"))
  ap.add_argument("--out", default=None, help="a folder for the two PNGs")
  args = ap.parse_args(argv)
  folders = sorted((pathlib.Path(args.data) / "tang2018").glob("DANCE_*"))
  rows = [(f.name, take_cues(f)) for f in folders]
  print("style  n  " + "  ".join(k for k, _ in CUES))
  for st in "CRTW":
    sel = [c for n, c in rows if n.split("_")[1] == st]
    print(f"{st:<5} {len(sel):2d}  " + "  ".join(f"{np.median([c[k] for c in sel]):+.1f}" for k, _ in CUES))
  if args.out:
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    plot_cues(rows, out / "tang_sides.png")
    w3 = next(f for f in folders if f.name == "DANCE_W_3")
    plot_pose(w3, -1, out / "tang_sides_pose.png")


if __name__ == "__main__":
  main()
