"""Golden fixtures for the engine's parity tests (tests/golden/README.md describes the format).

    /usr/bin/python3 -m training.fixtures --model models/test-tiny.dncw --out tests/golden/test-tiny
    /usr/bin/python3 -m training.fixtures --make-tiny          # writes models/test-tiny.dncw, then fixtures

Everything is computed by the torch modules rebuilt from the .dncw file itself (training.export.load_models),
in the streaming (step) form the engine uses. Output: .npy arrays (float32 / int32) and index.json.
"""
from __future__ import annotations

import argparse
import json
import pathlib

import numpy as np
import torch

from training.data import representation as rep
from training.data.skeleton import load_skeleton, project_bone_lengths
from training.export import export_model, load_models
from training.model.config import SeqConfig, VQConfig
from training.model.danceba import Danceba
from training.model.vqvae import DecoderStream, PoseVQVAE

REPO = pathlib.Path(__file__).resolve().parents[1]
STYLES = ["cha-cha", "rumba", "tango", "waltz", "salsa", "pop"]
FEATURES_META = {"feature_dim": 108, "pre_dim": 128, "sample_rate": 24000, "hop_samples": 800, "fps": 30,
                 "frames_per_step": 4, "lookahead_samples": 0, "layout": "docs/features.md"}
N_TRACE_STEPS = 6
N_GREEDY_STEPS = 256


def skeleton_meta() -> dict:
  skel = load_skeleton()
  d = skel.as_json()
  d["bone_lengths"] = skel.bone_lengths.tolist()
  d["upper_joints"] = [3, 6, 9, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22, 23]
  d["lower_joints"] = [0, 1, 2, 4, 5, 7, 8, 10, 11]
  d["lower_root_channels"] = {"vx": 27, "vz": 28, "yaw_rate": 29, "height": 30}
  return d


def make_tiny(path: pathlib.Path, seed: int = 1234) -> None:
  """A random-weight model with small dims but the real feature sizes; weights scaled up so that logits
  have clear margins (greedy parity is then robust to float rounding). Stored all-f32, so the engine's
  f32 path keeps a fixture of its own (the default model is mostly f16)."""
  torch.manual_seed(seed)
  cfg = SeqConfig(feature_dim=108, pre_dim=128, codebook_size=16, d_model=32, n_heads=2, n_base=2,
                  n_head=2, attn_window=8, d_state=8, d_conv=4, expand=2, n_styles=len(STYLES), style_dim=8)
  model = Danceba(cfg)
  with torch.no_grad():
    for name, p in model.named_parameters():
      if "A_log" in name or "dt_proj.bias" in name or name.endswith("norm1.weight") or "norm2" in name:
        continue
      p.add_(torch.randn_like(p) * 0.15)
    model.music_mean.copy_(torch.randn(cfg.music_dim) * 2)
    model.music_std.copy_(torch.rand(cfg.music_dim) * 3 + 0.5)
    bn = model.pre.bn
    bn.running_mean.copy_(torch.randn(cfg.d_model) * 0.1)
    bn.running_var.copy_(torch.rand(cfg.d_model) + 0.5)
    bn.weight.copy_(torch.rand(cfg.d_model) + 0.5)
    bn.bias.copy_(torch.randn(cfg.d_model) * 0.1)
    model.head_upper.weight.mul_(4)
    model.head_lower.weight.mul_(4)
  vqs = {}
  for part, dim in (("upper", 45), ("lower", 31)):
    vq = PoseVQVAE(VQConfig(in_dim=dim, width=32, code_dim=16, codebook_size=16, n_res=2))
    with torch.no_grad():
      vq.quantizer.codebook.copy_(torch.randn(16, 16))
      vq.quantizer.initialised.fill_(1)
      vq.pose_mean.copy_(torch.randn(dim) * 0.1)
      vq.pose_std.copy_(torch.rand(dim) * 0.1 + 0.02)
      if part == "lower":  # keep the root channels physically small: m/frame, rad/frame, height ~0.9 m
        vq.pose_mean[27:30] = 0.0
        vq.pose_std[27:30] = torch.tensor([0.005, 0.01, 0.01])
        vq.pose_mean[30] = 0.9
        vq.pose_std[30] = 0.02
    vqs[part] = vq
  export_model(str(path), model.eval(), vqs, {
      "model_id": "test-tiny", "description": "random weights, for parity tests only",
      "features": FEATURES_META, "skeleton": skeleton_meta(), "styles": STYLES}, weights_dtype="f32")


def _save(out: pathlib.Path, index: dict, name: str, arr, dtype=np.float32, note: str = "") -> None:
  a = np.ascontiguousarray(np.asarray(arr), dtype=dtype)
  np.save(out / f"{name}.npy", a)
  index["arrays"][name] = {"file": f"{name}.npy", "dtype": a.dtype.name, "shape": list(a.shape), "note": note}


@torch.no_grad()
def write_fixtures(model_path: pathlib.Path, out: pathlib.Path, seed: int = 7) -> dict:
  # The reference runs in float64 (the weights are the file's float32 values, exactly): the fixtures are
  # then the model's exact outputs to float32 rounding, and the engine's float32 error is its own, not the
  # sum of two float32 implementations' rounding.
  previous_dtype = torch.get_default_dtype()
  torch.set_default_dtype(torch.float64)
  try:
    return _write_fixtures(model_path, out, seed)
  finally:
    torch.set_default_dtype(previous_dtype)


def _write_fixtures(model_path: pathlib.Path, out: pathlib.Path, seed: int) -> dict:
  model, vqs, meta = load_models(str(model_path))
  cfg = model.cfg
  out.mkdir(parents=True, exist_ok=True)
  gen = np.random.default_rng(seed)
  k = cfg.codebook_size
  n = N_GREEDY_STEPS
  index = {"model": str(model_path.relative_to(REPO)) if model_path.is_absolute() and REPO in model_path.parents
           else str(model_path), "model_id": meta["model_id"], "arrays": {}}
  # Inputs: raw (un-normalised) per-frame features and PRE; the music token of step t is frames 4t..4t+3.
  mean = model.music_mean.numpy().reshape(4, -1).mean(0)
  std = model.music_std.numpy().reshape(4, -1).mean(0)
  frames = (mean + std * gen.standard_normal((4 * n, cfg.feature_dim))).astype(np.float32)
  pre_frames = np.clip(gen.standard_normal((4 * n, cfg.pre_dim)) * 0.6, -1, 1).astype(np.float32)
  style_w = np.zeros(cfg.n_styles + 1, np.float32)
  style_w[1], style_w[3] = 0.7, 0.3
  _save(out, index, "input_features", frames, note="(4N, F) raw per-frame music features")
  _save(out, index, "input_pre", pre_frames, note="(4N, P) per-frame PRE; step t uses frame 4t+3")
  _save(out, index, "input_style", style_w, note="(n_styles+1,) style weights (0.7 rumba + 0.3 waltz)")
  music = torch.from_numpy(frames.reshape(n, 4 * cfg.feature_dim).astype(np.float64))
  pre = torch.from_numpy(pre_frames[3::4].astype(np.float64))
  sw = torch.from_numpy(style_w.astype(np.float64))[None]

  # 1) Teacher-forced trace: fixed input codes, per-layer activations for the first steps.
  tf_u = gen.integers(0, k, N_TRACE_STEPS)
  tf_l = gen.integers(0, k, N_TRACE_STEPS)
  tf_u[0] = tf_l[0] = k  # BOS at step 0
  _save(out, index, "trace_codes_upper", tf_u, np.int32, "(S,) input upper codes per step (K = BOS)")
  _save(out, index, "trace_codes_lower", tf_l, np.int32, "(S,) input lower codes per step")
  traces: dict[str, list] = {}
  state = None
  for t in range(N_TRACE_STEPS):
    tr = {}
    lu, ll, state = model.step(music[t:t + 1], pre[t:t + 1], torch.tensor([tf_u[t]]), torch.tensor([tf_l[t]]),
                               sw, state, trace=tr)
    tr["logits_upper"], tr["logits_lower"] = lu, ll
    for name, v in tr.items():
      traces.setdefault(name, []).append(v[0].numpy())
  index["trace_layers"] = list(traces)
  for name, vals in traces.items():
    _save(out, index, f"trace_{name}", np.stack(vals), note="(S, 3, d) tokens (music, upper, lower)"
          if vals[0].ndim == 2 else "(S, K)")
  # Parallel form on the same inputs must match (checked here so a fixture never encodes a broken model).
  plu, pll = model(music[None, :N_TRACE_STEPS], pre[None, :N_TRACE_STEPS],
                   torch.from_numpy(tf_u)[None], torch.from_numpy(tf_l)[None], sw)
  assert np.allclose(plu[0].numpy(), np.stack(traces["logits_upper"]), atol=1e-4)

  # 2) Greedy generation from BOS for N steps: outputs are the codes of periods 1..N.
  u = torch.tensor([k])
  l = torch.tensor([k])
  state, codes_u, codes_l, logits_u, logits_l, margins = None, [], [], [], [], []
  for t in range(n):
    lu, ll, state = model.step(music[t:t + 1], pre[t:t + 1], u, l, sw, state)
    u, l = lu.argmax(-1), ll.argmax(-1)
    for lg in (lu, ll):
      top = torch.topk(lg[0], 2).values
      margins.append(float(top[0] - top[1]))
    codes_u.append(int(u))
    codes_l.append(int(l))
    logits_u.append(lu[0].numpy())
    logits_l.append(ll[0].numpy())
  index["greedy_min_margin"] = min(margins)
  _save(out, index, "greedy_codes_upper", codes_u, np.int32, "(N,) codes of periods 1..N")
  _save(out, index, "greedy_codes_lower", codes_l, np.int32, "(N,) codes of periods 1..N")
  _save(out, index, "greedy_logits_upper", np.stack(logits_u), note="(N, K) logits at each step")
  _save(out, index, "greedy_logits_lower", np.stack(logits_l), note="(N, K)")

  # 3) Streaming decode of the greedy codes, then root integration and bone projection.
  dec = {}
  for part, codes in (("upper", codes_u), ("lower", codes_l)):
    vq = vqs[part]
    stream = DecoderStream(vq.decoder, 1)
    frames_norm = torch.cat([stream.push(vq.quantizer.codebook[[c]]) for c in codes], dim=1)[0]
    full = vq.decode_codes(torch.tensor(codes)[None])[0]
    assert torch.allclose(full, frames_norm, atol=1e-4)
    dec[part] = vq.denormalise(frames_norm).numpy()
    _save(out, index, f"decoded_{part}_normalised", frames_norm.numpy(), note="(4N, dim) decoder output")
    _save(out, index, f"decoded_{part}", dec[part], note="(4N, dim) denormalised with pose_mean/std")
  positions = rep.decode(dec["upper"], dec["lower"])
  _save(out, index, "positions_raw", positions, note="(4N, 24, 3) after root integration, before projection")
  projected = project_bone_lengths(positions, load_skeleton())
  _save(out, index, "positions", projected, note="(4N, 24, 3) after bone-length projection (metres)")

  # 4) Encoder: the decoded lower/upper motion encoded back to codes (seed-motion path).
  for part in ("upper", "lower"):
    vq = vqs[part]
    enc_codes = vq.encode(vq.normalise(torch.from_numpy(dec[part][:64].astype(np.float64)))[None])[0]
    _save(out, index, f"encoder_input_{part}", dec[part][:64], note="(64, dim) denormalised pose features")
    _save(out, index, f"encoder_codes_{part}", enc_codes.numpy(), np.int32, "(16,) nearest codes")
  index["steps"] = n
  index["trace_steps"] = N_TRACE_STEPS
  with open(out / "index.json", "w") as f:
    json.dump(index, f, indent=1)
  return index


def main() -> None:
  ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  ap.add_argument("--model", default=str(REPO / "models" / "test-tiny.dncw"))
  ap.add_argument("--out", default=None, help="default: tests/golden/<model file stem>")
  ap.add_argument("--make-tiny", action="store_true", help="(re)write models/test-tiny.dncw first")
  args = ap.parse_args()
  torch.set_num_threads(1)
  model_path = pathlib.Path(args.model).resolve()
  if args.make_tiny:
    make_tiny(model_path)
  out = pathlib.Path(args.out) if args.out else REPO / "tests" / "golden" / model_path.stem
  index = write_fixtures(model_path, out)
  print(f"wrote {len(index['arrays'])} arrays to {out}; greedy min margin {index['greedy_min_margin']:.4f}")


if __name__ == "__main__":
  main()
