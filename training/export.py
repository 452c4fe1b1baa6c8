"""Writes and reads the `.dncw` weights file (docs/architecture.md, docs/weights-format.md).

    /usr/bin/python3 -m training.export --checkpoint training/runs/default/seq.pt --out models/default.dncw

Layout: "DNCW", u32 version 1, u64 header length, UTF-8 JSON header, zero padding to 64, tensors (each at a
multiple of 64 from the data start), u32 CRC-32 of everything before it. All tensors are little-endian f32.
"""
from __future__ import annotations

import argparse
import json
import struct
import zlib

import numpy as np
import torch

from training.model.config import SeqConfig, VQConfig
from training.model.danceba import Danceba
from training.model.vqvae import PoseVQVAE

MAGIC = b"DNCW"
VERSION = 1
ALIGN = 64
STREAM_NAMES = ("music", "upper", "lower")
PARTS = ("upper", "lower")


def _np(t: torch.Tensor) -> np.ndarray:
  return t.detach().cpu().float().numpy()


def _block_tensors(prefix: str, blk) -> dict[str, np.ndarray]:
  """Tensors of a TGCA block (has w_q) or a PMMM block (has mamba)."""
  out = {f"{prefix}.style.weight": _np(blk.style.proj.weight), f"{prefix}.style.bias": _np(blk.style.proj.bias),
         f"{prefix}.norm1.weight": _np(blk.norm1.weight), f"{prefix}.norm2.weight": _np(blk.norm2.weight),
         f"{prefix}.mlp.gate": _np(blk.mlp.gate.weight), f"{prefix}.mlp.up": _np(blk.mlp.up.weight),
         f"{prefix}.mlp.down": _np(blk.mlp.down.weight)}
  if hasattr(blk, "w_q"):
    for name in ("w_in", "w_q", "w_k", "w_v", "w_g", "w_o"):
      out[f"{prefix}.{name}"] = _np(getattr(blk, name).weight)
  else:
    m = blk.mamba
    out.update({f"{prefix}.mamba.in_proj": _np(m.in_proj.weight), f"{prefix}.mamba.conv_w": _np(m.conv_w),
                f"{prefix}.mamba.conv_b": _np(m.conv_b), f"{prefix}.mamba.x_proj": _np(m.x_proj.weight),
                f"{prefix}.mamba.dt_proj.weight": _np(m.dt_proj.weight),
                f"{prefix}.mamba.dt_proj.bias": _np(m.dt_proj.bias), f"{prefix}.mamba.A_log": _np(m.A_log),
                f"{prefix}.mamba.D": _np(m.D), f"{prefix}.mamba.out_proj": _np(m.out_proj.weight)})
  return out


def seq_tensors(model: Danceba) -> dict[str, np.ndarray]:
  cfg = model.cfg
  t = {"seq.music_mean": _np(model.music_mean), "seq.music_std": _np(model.music_std),
       "seq.embed.music.weight": _np(model.embed_music.weight),
       "seq.embed.music.bias": _np(model.embed_music.bias),
       "seq.embed.upper": _np(model.embed_upper.weight), "seq.embed.lower": _np(model.embed_lower.weight),
       "seq.embed.stream": _np(model.embed_stream), "seq.style.table": _np(model.style_table),
       "seq.norm_f.weight": _np(model.norm_f.weight), "seq.head.upper": _np(model.head_upper.weight),
       "seq.head.lower": _np(model.head_lower.weight)}
  if cfg.use_pre:
    scale, shift = model.pre.folded()
    t.update({"seq.pre.weight": _np(model.pre.linear.weight), "seq.pre.bias": _np(model.pre.linear.bias),
              "seq.pre.bn_scale": _np(scale), "seq.pre.bn_shift": _np(shift)})
  for i, blk in enumerate(model.base):
    t.update(_block_tensors(f"seq.base.{i}", blk))
  t.update(_block_tensors("seq.final", model.final))
  for i, sets in enumerate(model.pmmm):
    names = ("shared",) if len(sets) == 1 else STREAM_NAMES
    for name, blk in zip(names, sets):
      t.update(_block_tensors(f"seq.pmmm.{i}.{name}", blk))
  return t


def _ops_with_names(ops: list[dict], prefix: str) -> list[dict]:
  out = []
  for op in ops:
    op = dict(op)
    if op["op"] == "conv":
      i = op.pop("idx")
      op["w"], op["b"] = f"{prefix}.conv{i}.weight", f"{prefix}.conv{i}.bias"
    out.append(op)
  return out


def vq_tensors(part: str, vq: PoseVQVAE) -> tuple[dict[str, np.ndarray], dict]:
  p = f"vq.{part}"
  t = {f"{p}.pose_mean": _np(vq.pose_mean), f"{p}.pose_std": _np(vq.pose_std),
       f"{p}.codebook": _np(vq.quantizer.codebook)}
  for tag, net in (("dec", vq.decoder), ("enc", vq.encoder)):
    for i, conv in enumerate(net.convs):
      t[f"{p}.{tag}.conv{i}.weight"] = _np(conv.weight)
      t[f"{p}.{tag}.conv{i}.bias"] = _np(conv.bias)
  meta = dict(vq.cfg.to_dict(), downsample=4, codebook=f"{p}.codebook", pose_mean=f"{p}.pose_mean",
              pose_std=f"{p}.pose_std", decoder_ops=_ops_with_names(vq.decoder.ops, f"{p}.dec"),
              encoder_ops=_ops_with_names(vq.encoder.ops, f"{p}.enc"))
  return t, meta


def build_metadata(model: Danceba, vqs: dict[str, PoseVQVAE], extra: dict) -> dict:
  meta = {"model_id": extra.get("model_id", "unnamed"), "hyperparameters": model.cfg.to_dict(),
          "music_lookahead_steps": model.cfg.music_lookahead_steps}
  meta.update({k: v for k, v in extra.items() if k != "model_id"})
  meta["vq"] = {part: vq_tensors(part, vqs[part])[1] for part in PARTS}
  return meta


def _strict_json(value):
  """Replaces NaN/Inf floats (e.g. an undefined ratio in an eval report) by None: the header must be strict
  JSON, which the engine's parser requires (Python's json would otherwise write the non-standard NaN)."""
  if isinstance(value, float):
    return value if np.isfinite(value) else None
  if isinstance(value, dict):
    return {k: _strict_json(v) for k, v in value.items()}
  if isinstance(value, (list, tuple)):
    return [_strict_json(v) for v in value]
  return value


def write_dncw(path: str, tensors: dict[str, np.ndarray], metadata: dict) -> None:
  entries, blobs, offset = [], [], 0
  for name, arr in tensors.items():
    a = np.ascontiguousarray(arr, dtype="<f4")
    if not np.all(np.isfinite(a)):
      raise ValueError(f"tensor {name} has NaN or Inf")
    raw = a.tobytes()
    entries.append({"name": name, "dtype": "f32", "shape": list(a.shape), "offset": offset,
                    "nbytes": len(raw), "crc32": zlib.crc32(raw)})
    pad = (-len(raw)) % ALIGN
    blobs.append(raw + b"\0" * pad)
    offset += len(raw) + pad
  header = json.dumps({"format": "dance-weights", "version": VERSION, "metadata": _strict_json(metadata),
                       "tensors": entries}, separators=(",", ":"), allow_nan=False).encode()
  head = MAGIC + struct.pack("<IQ", VERSION, len(header)) + header
  head += b"\0" * ((-len(head)) % ALIGN)
  body = head + b"".join(blobs)
  with open(path, "wb") as f:
    f.write(body + struct.pack("<I", zlib.crc32(body)))


def read_dncw(path: str) -> tuple[dict, dict[str, np.ndarray]]:
  """Returns (header JSON, tensors), checking every field the engine checks."""
  with open(path, "rb") as f:
    buf = f.read()
  if buf[:4] != MAGIC:
    raise ValueError("bad magic")
  version, hlen = struct.unpack_from("<IQ", buf, 4)
  if version != VERSION:
    raise ValueError(f"unsupported version {version}")
  if struct.unpack_from("<I", buf, len(buf) - 4)[0] != zlib.crc32(buf[:-4]):
    raise ValueError("file CRC mismatch")
  header = json.loads(buf[16:16 + hlen].decode())
  data_start = 16 + hlen + ((-(16 + hlen)) % ALIGN)
  tensors = {}
  for e in header["tensors"]:
    start = data_start + e["offset"]
    if e["dtype"] != "f32" or e["offset"] % ALIGN or start + e["nbytes"] > len(buf) - 4:
      raise ValueError(f"bad tensor entry {e['name']}")
    if e["nbytes"] != 4 * int(np.prod(e["shape"])):
      raise ValueError(f"nbytes mismatch for {e['name']}")
    raw = buf[start:start + e["nbytes"]]
    if zlib.crc32(raw) != e["crc32"]:
      raise ValueError(f"CRC mismatch for {e['name']}")
    tensors[e["name"]] = np.frombuffer(raw, dtype="<f4").reshape(e["shape"]).copy()
  return header, tensors


def export_model(path: str, model: Danceba, vqs: dict[str, PoseVQVAE], extra: dict) -> dict:
  """Writes model + both VQ-VAEs to `path`; returns the metadata written."""
  tensors = seq_tensors(model)
  for part in PARTS:
    tensors.update(vq_tensors(part, vqs[part])[0])
  meta = build_metadata(model, vqs, extra)
  write_dncw(path, tensors, meta)
  return meta


# ---- loading back into torch (round trip, fixtures, evaluation of an exported file) -------------------
def _set(param: torch.Tensor, arr: np.ndarray, name: str) -> None:
  if tuple(param.shape) != tuple(arr.shape):
    raise ValueError(f"{name}: file shape {arr.shape} != model shape {tuple(param.shape)}")
  with torch.no_grad():
    param.copy_(torch.from_numpy(arr))


def load_models(path: str) -> tuple[Danceba, dict[str, PoseVQVAE], dict]:
  """Rebuilds (Danceba, {upper, lower}: PoseVQVAE, metadata) in eval mode from a .dncw file."""
  header, t = read_dncw(path)
  meta = header["metadata"]
  cfg = SeqConfig.from_dict(meta["hyperparameters"])
  model = Danceba(cfg).eval()
  mine = seq_tensors(model)  # names and shapes the model expects
  missing = set(mine) - set(t)
  if missing:
    raise ValueError(f"missing tensors: {sorted(missing)[:5]}")
  params = dict(model.named_parameters())
  params.update(dict(model.named_buffers()))
  for name in mine:
    if name.startswith("seq.pre.bn_"):
      continue
    target = _torch_param(model, name)
    _set(target, t[name], name)
  if cfg.use_pre:  # store the folded BatchNorm as an identity-statistics BatchNorm
    bn = model.pre.bn
    with torch.no_grad():
      bn.running_mean.zero_()
      bn.running_var.fill_(1.0 - bn.eps)
      bn.weight.copy_(torch.from_numpy(t["seq.pre.bn_scale"]))
      bn.bias.copy_(torch.from_numpy(t["seq.pre.bn_shift"]))
  vqs = {}
  for part in PARTS:
    vcfg = VQConfig.from_dict(meta["vq"][part])
    vq = PoseVQVAE(vcfg).eval()
    p = f"vq.{part}"
    _set(vq.pose_mean, t[f"{p}.pose_mean"], "pose_mean")
    _set(vq.pose_std, t[f"{p}.pose_std"], "pose_std")
    _set(vq.quantizer.codebook, t[f"{p}.codebook"], "codebook")
    vq.quantizer.initialised.fill_(1)
    for tag, net in (("dec", vq.decoder), ("enc", vq.encoder)):
      for i, conv in enumerate(net.convs):
        _set(conv.weight, t[f"{p}.{tag}.conv{i}.weight"], "conv")
        _set(conv.bias, t[f"{p}.{tag}.conv{i}.bias"], "conv")
    vqs[part] = vq
  return model, vqs, meta


def _torch_param(model: Danceba, name: str) -> torch.Tensor:
  """Maps an exported tensor name back to the module's parameter or buffer."""
  fixed = {"seq.music_mean": model.music_mean, "seq.music_std": model.music_std,
           "seq.embed.music.weight": model.embed_music.weight, "seq.embed.music.bias": model.embed_music.bias,
           "seq.embed.upper": model.embed_upper.weight, "seq.embed.lower": model.embed_lower.weight,
           "seq.embed.stream": model.embed_stream, "seq.style.table": model.style_table,
           "seq.norm_f.weight": model.norm_f.weight, "seq.head.upper": model.head_upper.weight,
           "seq.head.lower": model.head_lower.weight, "seq.pre.weight": model.pre.linear.weight,
           "seq.pre.bias": model.pre.linear.bias}
  if name in fixed:
    return fixed[name]
  parts = name.split(".")
  if parts[1] == "base":
    blk, rest = model.base[int(parts[2])], parts[3:]
  elif parts[1] == "final":
    blk, rest = model.final, parts[2:]
  else:  # seq.pmmm.i.stream...
    sets = model.pmmm[int(parts[2])]
    blk = sets[0] if parts[3] == "shared" else sets[STREAM_NAMES.index(parts[3])]
    rest = parts[4:]
  attr = {"style.weight": "style.proj.weight", "style.bias": "style.proj.bias", "mlp.gate": "mlp.gate.weight",
          "mlp.up": "mlp.up.weight", "mlp.down": "mlp.down.weight", "mamba.in_proj": "mamba.in_proj.weight",
          "mamba.x_proj": "mamba.x_proj.weight", "mamba.out_proj": "mamba.out_proj.weight"}
  key = ".".join(rest)
  key = attr.get(key, key)
  if key in ("w_in", "w_q", "w_k", "w_v", "w_g", "w_o"):
    key += ".weight"
  obj = blk
  for a in key.split("."):
    obj = getattr(obj, a)
  return obj


def main() -> None:
  ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  ap.add_argument("--check", help="read a .dncw file, validate it and print a summary")
  args = ap.parse_args()
  if args.check:
    header, t = read_dncw(args.check)
    n = sum(a.size for a in t.values())
    print(f"{args.check}: {len(t)} tensors, {n} parameters, model_id={header['metadata']['model_id']}")


if __name__ == "__main__":
  main()
