"""The controls measured (docs/controls.md): SGMD's Table III protocol on the validation songs with the token
model's controls, run by the engine (dance-generate), beside the unconstrained model and the real dances.

For every validation song the conditions are taken from its real dance (placed on the song's timeline by
its audio offset): the trajectory is its root path (a point every 0.5 s), the seed its first 4 s, the
keyframes one pose every 2 s, the inpainting mask keeps all but the middle third, the given halves are its
upper or lower body. Each task's dances are cut to the real spans (evaluate.on_real_spans) and scored with
evaluate.Evaluator (FID_k, FID_g, Div_k, Div_g, BAS, PFC, ...), plus each control's own error and the seam
jump (the largest joint speed within 0.5 s of a seam, against the real dances' 95th percentile of each
frame's largest joint speed).

Usage:
  OMP_WAIT_POLICY=PASSIVE .venv/bin/python -m training.eval.controls_eval --model models/default.dncw \\
      --out-dir training/runs/controls [--seed 0] [--songs tang_DANCE_W_3,...] [--render]
Writes OUT/controls_report.json and OUT/controls_report.md (the table docs/controls.md quotes) and, with
--render, OUT/strip_<task>.png around a seam of the first song.
"""
from __future__ import annotations

import argparse
import json
import pathlib

import numpy as np

from training import tools
from training.eval import evaluate
from training.eval.evaluate import Dance
from training.eval.render import render_strip

TASKS = ("unconstrained", "trajectory", "seed", "inbetween", "inpaint", "upper_generated", "lower_generated")
UPPER = [3, 6, 9, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22, 23]
LOWER = [0, 1, 2, 4, 5, 7, 8, 10, 11]
SEED_S, KEY_EVERY_S, PATH_EVERY_S, SEAM_S = 4.0, 2.0, 0.5, 0.5


def _motion_doc(positions: np.ndarray, offset_s: float, **extra) -> dict:
  doc = {"format": "dance-motion/v1", "fps": 30, "units": "m", "up_axis": "y",
         "positions": np.round(positions, 6).tolist(), "audio_offset_s": float(offset_s)}
  doc.update(extra)
  return doc


def write_conditions(real: Dance, out: pathlib.Path) -> dict:
  """The control files of one real dance; returns the flags of each task and its seams (audio seconds)."""
  out.mkdir(parents=True, exist_ok=True)
  p, off, n = real.positions, real.audio_offset_s, len(real.positions)
  (out / "real.json").write_text(json.dumps(_motion_doc(p, off)))
  seed_n = int(SEED_S * 30)
  (out / "seed.json").write_text(json.dumps(_motion_doc(p[:seed_n], off)))
  keys = list(range(int(KEY_EVERY_S * 30), n, int(KEY_EVERY_S * 30)))
  (out / "keys.json").write_text(json.dumps(_motion_doc(p[keys], 0.0, times_s=[off + k / 30 for k in keys])))
  a, b = n // 3, 2 * n // 3
  (out / "mask.json").write_text(json.dumps({"format": "dance-mask/v1", "known": [
      {"start_s": off, "end_s": off + a / 30, "joints": ["all"]},
      {"start_s": off + b / 30, "end_s": off + n / 30, "joints": ["all"]}]}))
  step = int(PATH_EVERY_S * 30)
  pts = [{"t": off + i / 30, "x": float(p[i, 0, 0]), "z": float(p[i, 0, 2])} for i in range(0, n, step)]
  (out / "path.json").write_text(json.dumps({"format": "dance-trajectory/v1", "points": pts}))
  real_json = str(out / "real.json")
  return {
      "unconstrained": ([], []),
      "trajectory": (["--trajectory", str(out / "path.json")], []),
      "seed": (["--seed-motion", str(out / "seed.json")], [off + seed_n / 30]),
      "inbetween": (["--keyframes", str(out / "keys.json")], [off + k / 30 for k in keys]),
      "inpaint": (["--inpaint", real_json, "--mask", str(out / "mask.json")], [off + a / 30, off + b / 30]),
      "upper_generated": (["--given-lower", real_json], []),
      "lower_generated": (["--given-upper", real_json], []),
  }


def _hip_frame(p: np.ndarray) -> np.ndarray:
  """(T, 24, 3) -> each joint relative to the pelvis in the frame of the hips (the halves' frame)."""
  a = p[:, 1] - p[:, 2]
  yaw = np.arctan2(-a[:, 2], a[:, 0])
  c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
  d = p - p[:, :1]
  return np.stack([c * d[..., 0] - s * d[..., 2], d[..., 1], s * d[..., 0] + c * d[..., 2]], axis=-1)


def _max_speed(p: np.ndarray) -> np.ndarray:
  """(T, 24, 3) -> (T - 1,) the largest joint speed of each frame step, m/s."""
  return np.linalg.norm(np.diff(p, axis=0), axis=-1).max(axis=1) * 30.0


def constraint_errors(task: str, gen: Dance, real: Dance, seams_s: list[float]) -> dict:
  """The task's own errors on the real span (gen already cut to it): cm, and the seam jump in m/s."""
  # The engine's first frame is audio frame 4: a real dance starting before that is compared from there.
  shift = max(0, int(round((gen.audio_offset_s - real.audio_offset_s) * 30)))
  r = real.positions[shift:shift + len(gen.positions)]
  g = gen.positions[:len(r)]
  out = {}
  if task == "trajectory":
    d = np.linalg.norm(g[:, 0, [0, 2]] - r[:, 0, [0, 2]], axis=-1) * 100
    out.update(traj_mean_cm=float(d.mean()), traj_max_cm=float(d.max()))
  elif task == "inbetween":
    keys = [k - shift for k in range(int(KEY_EVERY_S * 30), len(g) + shift, int(KEY_EVERY_S * 30)) if k >= shift]
    out["key_err_cm"] = float(np.mean([np.linalg.norm(g[k] - r[k], axis=-1).mean() for k in keys]) * 100)
  elif task == "seed":
    n = int(SEED_S * 30) - shift
    out["given_err_cm"] = float(np.linalg.norm(g[:n] - r[:n], axis=-1).max() * 100)
  elif task == "inpaint":
    a, b = len(real.positions) // 3 - shift, 2 * len(real.positions) // 3 - shift
    known = np.r_[0:a, b:len(g)]
    out["given_err_cm"] = float(np.linalg.norm(g[known] - r[known], axis=-1).max() * 100)
  elif task == "upper_generated":  # the lower body was given: global
    out["given_err_cm"] = float(np.linalg.norm(g[:, LOWER] - r[:, LOWER], axis=-1).max() * 100)
  elif task == "lower_generated":  # the upper body was given: relative to the hips
    out["given_err_cm"] = float(np.linalg.norm(_hip_frame(g)[:, UPPER] - _hip_frame(r)[:, UPPER], axis=-1).max() * 100)
  if seams_s:
    speed = _max_speed(g)
    jumps = []
    for t in seams_s:
      i = int(round((t - gen.audio_offset_s) * 30))
      lo, hi = max(0, i - int(SEAM_S * 30)), min(len(speed), i + int(SEAM_S * 30))
      if hi > lo:
        jumps.append(float(speed[lo:hi].max()))
    if jumps:
      out.update(seam_jump_max=float(np.max(jumps)), seam_jump_mean=float(np.mean(jumps)))
  return out


def generate(model: str, real: Dance, flags: list[str], out: pathlib.Path, seed: int) -> tuple[Dance, dict]:
  """One task's dance of one song through the engine; returns it and dance-generate's summary (wall_s,
  audio_s, steps, x_real_time, ...)."""
  summary = tools.dance_generate_summary(model, real.audio_path, out, seed=seed, style=real.style, extra=flags)
  d = evaluate.load_dance(out, audio=real.audio_path)
  d.name, d.style = real.name, real.style
  return d, summary


def main(argv=None) -> int:
  ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
  ap.add_argument("--model", default="models/default.dncw")
  ap.add_argument("--out-dir", required=True)
  ap.add_argument("--seed", type=int, default=0)
  ap.add_argument("--songs", default="", help="comma-separated validation ids (default: all Tang validation)")
  ap.add_argument("--tasks", default=",".join(TASKS), help="comma-separated subset of " + ", ".join(TASKS))
  ap.add_argument("--render", action="store_true")
  ap.add_argument("--extra", default="", help="more dance-generate flags for every dance, e.g. '--steps 25'")
  args = ap.parse_args(argv)
  tasks = [t for t in args.tasks.split(",") if t]
  for t in tasks:
    if t not in TASKS:
      raise SystemExit(f"controls_eval: unknown task '{t}' (known: {', '.join(TASKS)})")
  out = pathlib.Path(args.out_dir)
  out.mkdir(parents=True, exist_ok=True)
  ids = [s for s in args.songs.split(",") if s] or evaluate.split_ids("validation")
  real = evaluate.cached_dances(ids)
  ev = evaluate.Evaluator.default()
  speeds = np.concatenate([_max_speed(r.positions) for r in real])
  report = {"model": args.model, "seed": args.seed, "songs": ids, "extra_flags": args.extra,
            "real_p95_max_joint_speed": float(np.percentile(speeds, 95)), "tasks": {}}
  conditions = {r.name: write_conditions(r, out / "inputs" / r.name) for r in real}
  first_seams = {}
  for task in tasks:
    dances, errors, step_ms = [], [], []
    (out / "dances" / task).mkdir(parents=True, exist_ok=True)
    for r in real:
      flags, seams = conditions[r.name][task]
      d, summary = generate(args.model, r, flags + args.extra.split(), out / "dances" / task / f"{r.name}.json",
                            args.seed)
      cut = evaluate.on_real_spans([d], [r])[0]
      dances.append(cut)
      errors.append(constraint_errors(task, cut, r, seams))
      step_ms.append(summary)
      if r is real[0]:
        first_seams[task] = (d, seams)
    row = ev.evaluate(dances)
    for key in sorted({k for e in errors for k in e}):
      vals = [e[key] for e in errors if key in e]
      row[key] = float(np.max(vals) if key.endswith("_max") or key.endswith("_max_cm") or key == "given_err_cm"
                       else np.mean(vals))
    if summary.get("backend") != "diffusion":  # the token model's wall time per step
      row["step_ms"] = float(np.mean([x["wall_s"] / max(x["steps"], 1) * 1000.0 for x in step_ms]))
    row["x_real_time"] = float(np.sum([x["audio_s"] for x in step_ms]) / np.sum([x["wall_s"] for x in step_ms]))
    report["tasks"][task] = row
    print(task, json.dumps({k: round(v, 3) for k, v in row.items() if isinstance(v, float)}), flush=True)
  report["tasks"]["real"] = ev.evaluate(real)
  (out / "controls_report.json").write_text(json.dumps(report, indent=1))
  (out / "controls_report.md").write_text(markdown(report))
  if args.render:
    for task, (d, seams) in first_seams.items():
      t = (seams[0] if seams else d.audio_offset_s + 20.0) - 1.0
      render_strip(d.positions, str(out / f"strip_{task}.png"), fps=30, start_s=t - d.audio_offset_s, n=8,
                   step_s=0.25, title=f"{task}: {real[0].name} from {t:.1f} s")
  return 0


def markdown(report: dict) -> str:
  cols = ["fid_k", "fid_g", "div_k", "div_g", "bas", "pfc", "jitter", "foot_skate"]
  extra = ["traj_mean_cm", "traj_max_cm", "key_err_cm", "given_err_cm", "seam_jump_max", "step_ms", "x_real_time"]
  head = "| task | " + " | ".join(cols + extra) + " |\n|---|" + "---|" * (len(cols) + len(extra)) + "\n"
  lines = []
  for task, r in report["tasks"].items():
    cells = [f"{r[k]:.3g}" if k in r and r[k] == r[k] else "" for k in cols + extra]
    lines.append(f"| {task} | " + " | ".join(cells) + " |")
  return head + "\n".join(lines) + f"\n\nReal dances' 95th percentile of the largest joint speed per frame: " \
      f"{report['real_p95_max_joint_speed']:.2f} m/s. Model {report['model']}, seed {report['seed']}.\n"


if __name__ == "__main__":
  raise SystemExit(main())
