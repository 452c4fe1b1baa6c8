"""Golden fixtures for the engine's SGMD (tests/golden/README.md, "SGMD"): the denoiser and the sampler of
docs/diffusion.md run in PyTorch on a model file, for the engine to reproduce.

    /usr/bin/python3 -m training.diffusion.fixtures --make-tiny          # models/sgmd-tiny.dncw + tests/golden/sgmd-tiny/
    /usr/bin/python3 -m training.diffusion.fixtures --model models/sgmd.dncw   # -> tests/golden/sgmd/

Each directory has `sgmd.json` (not `index.json`: the token model's golden test reads those) naming the model
and the arrays (.npy, float32, C order).
"""
from __future__ import annotations

import argparse
import json
import pathlib

import numpy as np
import torch

from training.common.clips import REPO, STYLES
from training.diffusion import motion
from training.diffusion.data import Stats
from training.diffusion.export import export_sgmd, load_sgmd
from training.diffusion.sample import ddim_window
from training.data.skeleton import load_skeleton
from training.model.sgmd import SGMD, SGMDConfig

TINY = dict(d_model=32, n_heads=2, n_layers=2, n_music_layers=1, frames=8, frames_per_token=2, style_dim=8,
            n_styles=len(STYLES), dropout=0.0, prediction="v")  # the engine's v form checked against PyTorch (the shipped model is x0)


def make_tiny(path: pathlib.Path) -> None:
  torch.manual_seed(7)
  model = SGMD(SGMDConfig(**TINY)).eval()
  with torch.no_grad():
    for name, p in model.named_parameters():
      p.normal_(0.0, 0.3 if "norm" not in name else 0.1).add_(1.0 if name.endswith("norm1.weight") else 0.0)
  rng = np.random.default_rng(7)
  stats = Stats(rng.normal(0, 0.3, motion.POSE_DIM), rng.uniform(0.5, 2.0, motion.POSE_DIM),
                rng.normal(0, 0.3, 108), rng.uniform(0.5, 2.0, 108))
  export_sgmd(str(path), model, stats, STYLES, {"model_id": "sgmd-tiny", "description": "random weights, for "
              "the engine's parity tests only"}, weights_dtype="f32")


def write_fixtures(model_path: pathlib.Path, out: pathlib.Path) -> dict:
  model, stats, meta = load_sgmd(str(model_path))
  cfg = model.cfg
  out.mkdir(parents=True, exist_ok=True)
  rng = np.random.default_rng(11)
  g = torch.Generator().manual_seed(11)
  index = {"model": str(model_path.relative_to(REPO)) if REPO in model_path.resolve().parents else str(model_path),
           "model_id": meta["model_id"], "arrays": {}}

  def save(name: str, a, note: str) -> None:
    a = np.ascontiguousarray(np.asarray(a, dtype=np.float32))
    np.save(out / f"{name}.npy", a)
    index["arrays"][name] = {"file": f"{name}.npy", "shape": list(a.shape), "note": note}

  n, dd = cfg.frames, cfg.pose_dim
  music = torch.from_numpy(rng.normal(0, 1, (cfg.tokens, cfg.music_dim))).float()[None]
  x_t = torch.randn(1, n, dd, generator=g)
  style = torch.zeros(1, cfg.n_styles + 1)
  style[0, 1], style[0, cfg.n_styles] = 0.7, 0.3
  t = 537
  with torch.no_grad():
    c = model.encode_music(music, torch.ones(1, dtype=torch.bool))
    x0 = model.denoise(x_t, torch.tensor([t]), c, style)
    x0_null = model.denoise(x_t, torch.tensor([t]), model.music_null[None], style)
  save("input_music", music[0], "(n, 2 (F+P)) music tokens, already normalised")
  save("input_x_t", x_t[0], "(N, D) the noised motion (normalised)")
  save("input_style", style[0], "(n_styles+1,) style weights: 0.7 style 1 + 0.3 none")
  index["t"] = t
  save("music_tokens", c[0], "(n, d) the music encoder's output")
  save("x0_cond", x0[0], "(N, D) D(x_t, t, c, sv)")
  save("x0_null", x0_null[0], "(N, D) D(x_t, t, music_null, sv)")
  noise = torch.randn(n, dd, generator=g)
  known = torch.randn(n, dd, generator=g)
  mask = torch.zeros(n, dd)
  mask[:2] = 1.0                 # the first two frames, every dim
  mask[:, 0:3] = 1.0             # the pelvis everywhere
  mask[n - 1, 5:20] = 1.0        # some joints of the last frame
  steps, guidance = 5, 2.0
  x = ddim_window(model, c, model.music_null[None], style, noise, steps, guidance, known, mask)
  x_free = ddim_window(model, c, model.music_null[None], style, noise, steps, 1.0)
  index.update({"ddim_steps": steps, "ddim_guidance": guidance})
  save("ddim_noise", noise, "(N, D) the window's noise e")
  save("ddim_known", known, "(N, D) known values (normalised)")
  save("ddim_mask", mask, "(N, D) 1 = known")
  save("ddim_out", x, f"(N, D) DDIM, {steps} steps, guidance {guidance}, with the mask")
  save("ddim_free", x_free, f"(N, D) DDIM, {steps} steps, guidance 1, no mask")
  # The motion vector of a real-looking pose sequence (section 2): a rotated, translated walk.
  pos = _walk(24)
  save("vector_positions", pos, "(24, 24, 3) world positions")
  save("vector_out", motion.motion_vector(pos), "(24, 78) their motion vectors (in their own frame)")
  yaw, origin = motion.frame_of(pos[0])
  save("canonical_positions", motion.positions_in_frame(pos, yaw, origin), "(24, 24, 3) in frame 0's canonical frame")
  (out / "sgmd.json").write_text(json.dumps(index, indent=1) + "\n")
  return index


def _walk(t: int) -> np.ndarray:
  skel = load_skeleton()
  rest = np.zeros((24, 3))
  for j in range(24):
    p = skel.parents[j]
    rest[j] = rest[p] + skel.offsets[j] if p >= 0 else (0.0, 0.95, 0.0)
  out = np.zeros((t, 24, 3))
  for i in range(t):
    a = 0.4 + 0.05 * i
    r = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    pose = rest.copy()
    pose[[7, 10]] += (0.0, 0.0, 0.1 * np.sin(0.5 * i))
    out[i] = pose @ r.T + (1.0 + 0.02 * i, 0.0, -0.5 + 0.01 * i * i)
  return out


def main(argv: list[str] | None = None) -> None:
  ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
  ap.add_argument("--make-tiny", action="store_true")
  ap.add_argument("--model", default="")
  ap.add_argument("--out", default="")
  args = ap.parse_args(argv)
  if args.make_tiny:
    path = REPO / "models" / "sgmd-tiny.dncw"
    make_tiny(path)
    write_fixtures(path, pathlib.Path(args.out) if args.out else REPO / "tests" / "golden" / "sgmd-tiny")
  elif args.model:
    path = pathlib.Path(args.model).resolve()
    write_fixtures(path, pathlib.Path(args.out) if args.out else REPO / "tests" / "golden" / path.stem)
  else:
    ap.error("--make-tiny or --model")


if __name__ == "__main__":
  main()
