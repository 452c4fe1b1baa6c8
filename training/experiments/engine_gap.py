"""Where the free-running screen and the engine part: the same model's FID on the validation songs' real
spans, measured four ways that differ by one thing each (docs/research-log.md, "The engine against the
PyTorch model").

    DANCE_BUILD_DIR=build-h40 /usr/bin/python3 -m training.experiments.engine_gap --model M.dncw \
        --out-dir D [--seeds 0,1,2,3] [--guidance G]

Per seed (one draw of every validation song in its own style):
- `screen`: the free_run screen (training.experiments.free_run --fid): the PyTorch model free-running from
  BOS at the start of the real dance's span on the warped timeline, decoded by the file's VQ decoders,
  scored in warped time (no engine locks).
- `whole_warped`: the engine's codes over the whole song from its first step (`dance-generate --codes-out`,
  period lock and crouch guard off; the same codes the PyTorch model draws, training.eval.engine_parity),
  decoded the same way and cut to the span's warped frames: differs from `screen` only in where the dance
  starts (the song's start, not the span's).
- `engine_raw`: the same run's dance as the engine plays it (real time, foot lock off), cut to the real
  span (evaluate.on_real_spans): differs from `whole_warped` only in the time base (warped poses shown on the
  real 30 fps timeline) and the engine's decode.
- `engine`: `dance-generate` with the model's defaults (period lock, crouch guard, foot lock), as
  training.eval.engine_eval scores it on the spans.
--sets picks some of them, or the engine with one lock off (engine_no_period_lock, engine_no_foot_lock,
engine_no_crouch_guard). Writes D/gap.json and prints FID_k / FID_g / segments per set and seed and their means.
"""
from __future__ import annotations

import argparse
import json
import pathlib

import numpy as np
import torch

from training import tools
from training.common import clips as td
from training.data import skeleton as sk
from training.eval import evaluate
from training.eval.engine_parity import EngineSampler, song_tokens
from training.experiments.free_run import decode_codes
from training.export import load_models
from training.features.extract import extract_clock, extract_features
from training.model.danceba import one_hot_style

SETS = ("screen", "whole_warped", "engine_raw", "engine")
# Splitting the engine's locks (with --sets): the defaults with one lock off.
ENGINE_VARIANTS = {"engine": [], "engine_no_period_lock": ["--period-lock", 0],
                   "engine_no_foot_lock": ["--foot-lock", 0], "engine_no_crouch_guard": ["--crouch-guard", 0]}
ALL_SETS = SETS[:3] + tuple(ENGINE_VARIANTS)


def span_on_warped(mid: str, reference_bpm: float, frames_per_step: int = 4) -> tuple[int, int]:
  """The warped frames [j0, j0 + 4 n) of the real dance's span, as clips.load_warped_clip cuts them."""
  z = np.load(td.MOTION_CACHE / f"{mid}.npz")
  audio = str(z["audio_path"])
  m = extract_features(audio, cache_dir=td.FEATURE_CACHE)
  clock = extract_clock(audio, reference_bpm, cache_dir=td.FEATURE_CACHE).astype(np.float64)
  n0 = int(round(float(z["audio_offset_s"]) * 30))
  src, x = clock[:, 0].astype(np.int64), clock[:, 1] - n0
  ok = np.flatnonzero((x >= 0) & (x <= len(z["positions"]) - 1) & (src < len(m["features"])))
  j0 = int(-(-ok[0] // frames_per_step) * frames_per_step)
  n = (ok[-1] + 1 - j0) // frames_per_step
  return j0, j0 + frames_per_step * n


@torch.no_grad()
def screen_codes(model, music: np.ndarray, pre: np.ndarray, style: int, seed: int, guidance: float) -> np.ndarray:
  """(steps, 2) codes free-running from BOS over the given tokens (the screen), drawn by EngineSampler."""
  cfg, k = model.cfg, model.cfg.codebook_size
  sampler = EngineSampler(seed)
  cond, uncond = one_hot_style(1, style, cfg.n_styles), one_hot_style(1, -1, cfg.n_styles)
  u = l = torch.full((1,), k, dtype=torch.long)
  sc = su = None
  out = np.zeros((len(music), 2), np.int64)
  for t in range(len(music)):
    m, p = torch.from_numpy(music[t])[None], torch.from_numpy(pre[t])[None]
    cu, cl, sc = model.step(m, p, u, l, cond, sc)
    if guidance != 1.0:
      uu, ul, su = model.step(m, p, u, l, uncond, su)
      cu, cl = uu + guidance * (cu - uu), ul + guidance * (cl - ul)
    out[t] = sampler(cu[0].numpy()), sampler(cl[0].numpy())
    u, l = torch.tensor([out[t, 0]]), torch.tensor([out[t, 1]])
  return out


def song_draws(model_path: str, model, vqs, meta, mid: str, seed: int, guidance: float, work: pathlib.Path,
               skel, sets=SETS) -> dict[str, evaluate.Dance]:
  z = np.load(td.MOTION_CACHE / f"{mid}.npz")
  audio, style = str(z["audio_path"]), str(z["style"])
  tb = meta["time_base"]
  ref = float(tb.get("style_reference_bpm", {}).get(style, tb["reference_bpm"]))
  j0, j1 = span_on_warped(mid, ref)
  music, pre = song_tokens(audio, ref)
  s0, s1 = j0 // 4, j1 // 4
  out, paths = {}, {}
  if "screen" in sets:
    # From BOS at the span's first step, on the span's tokens (steps s0 .. s1 - 2 draw periods s0 + 1 ..).
    sc = screen_codes(model, music[s0:s1 - 1], pre[s0:s1 - 1], meta["styles"].index(style), seed, guidance)
    out["screen"] = decode_codes(vqs, sc[:, 0], sc[:, 1], mid, skel)
  if "whole_warped" in sets or "engine_raw" in sets:
    codes = work / f"{mid}_s{seed}_codes.npy"
    paths["engine_raw"] = work / f"{mid}_s{seed}_raw.json"
    tools.dance_generate_summary(model_path, audio, paths["engine_raw"], seed=seed, style=style,
                                 extra=["--codes-out", codes, "--period-lock", 0, "--crouch-guard", 0,
                                        "--foot-lock", 0])
    ec = np.load(codes).astype(np.int64)
    whole = decode_codes(vqs, ec[:, 0], ec[:, 1], mid, skel)  # warped frame 4 + i is decoded frame i
    a, b = max(0, j0 - 4), max(0, j1 - 4)
    out["whole_warped"] = evaluate.Dance(mid, whole.positions[a:b], 30.0)
  for name, extra in ENGINE_VARIANTS.items():
    if name in sets:
      paths[name] = work / f"{mid}_s{seed}_{name}.json"
      tools.dance_generate_summary(model_path, audio, paths[name], seed=seed, style=style, extra=extra)
  for name, path in paths.items():
    d = evaluate.load_dance(path, audio=audio)
    out[name] = evaluate.Dance(mid, d.positions, d.fps, d.audio_path, d.audio_offset_s, style)
  return {k: v for k, v in out.items() if k in sets}


def main(argv=None) -> None:
  ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
  ap.add_argument("--model", default="models/default.dncw")
  ap.add_argument("--out-dir", required=True)
  ap.add_argument("--seeds", default="0,1,2,3")
  ap.add_argument("--guidance", type=float, default=None, help="default: the model's")
  ap.add_argument("--sets", default=",".join(SETS), help=f"comma-separated, of {', '.join(ALL_SETS)}")
  args = ap.parse_args(argv)
  sets = tuple(args.sets.split(","))
  if not set(sets) <= set(ALL_SETS):
    ap.error(f"--sets: unknown {sorted(set(sets) - set(ALL_SETS))}")
  torch.set_grad_enabled(False)
  td.ensure_motion_cache()
  model, vqs, meta = load_models(args.model)
  guidance = float(meta.get("sampling", {}).get("guidance", 1.0)) if args.guidance is None else args.guidance
  if float(meta.get("sampling", {}).get("music_guidance", 1.0)) != 1.0:
    raise SystemExit("engine_gap: models with music guidance are not covered (the screen reads the song's music)")
  work = pathlib.Path(args.out_dir)
  work.mkdir(parents=True, exist_ok=True)
  ev, skel = evaluate.Evaluator.default(), sk.load_skeleton()
  ids = td.tang_ids(td.load_split()["validation"])
  result = {s: [] for s in sets}
  for seed in (int(s) for s in args.seeds.split(",")):
    dances = {s: [] for s in sets}
    for mid in ids:
      for name, d in song_draws(args.model, model, vqs, meta, mid, seed, guidance, work, skel, sets).items():
        dances[name].append(d)
    for name in sets:
      if name.startswith("engine"):  # real-time dances of whole songs: cut to the real spans
        dances[name] = evaluate.on_real_spans(dances[name], ev.validation)
    for name in sets:
      r = ev.fid_div(dances[name])
      result[name].append(r)
      print(f"seed {seed} {name:<13} FID_k {r['fid_k']:6.2f}  FID_g {r['fid_g']:5.2f}  Div_k {r['div_k']:5.2f}  "
            f"segments {r['segments']}", flush=True)
    (work / "gap.json").write_text(json.dumps(result, indent=1))
  for name in sets:
    fk, fg = [r["fid_k"] for r in result[name]], [r["fid_g"] for r in result[name]]
    print(f"mean {name:<13} FID_k {np.mean(fk):6.2f} ({' '.join(f'{v:.2f}' for v in fk)})  FID_g {np.mean(fg):5.2f}")


if __name__ == "__main__":
  main()
