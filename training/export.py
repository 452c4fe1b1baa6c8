"""Writes and reads the `.dncw` weights file (docs/architecture.md, docs/weights-format.md).

    /usr/bin/python3 -m training.export --check models/default.dncw
    /usr/bin/python3 -m training.export --convert IN.dncw OUT.dncw --dtype f16   # or --dtype f32

Layout: "DNCW", u32 version 1, u64 header length, UTF-8 JSON header, zero padding to 64, tensors (each at a
multiple of 64 from the data start), u32 CRC-32 of everything before it. Tensors are little-endian "f32"
(IEEE binary32) or "f16" (IEEE binary16); readers widen f16 to float32. Which tensors are stored as f16 is
decided by `f16_policy` (exports made by training.train use it unless told `--weights-dtype f32`).
"""
from __future__ import annotations

import argparse
import fnmatch
import json
import os
import struct
import zlib
from collections.abc import Mapping

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
DTYPES = {"f32": np.dtype("<f4"), "f16": np.dtype("<f2")}  # file dtype -> how its bytes are stored

# f16 policy (docs/weights-format.md). Stored as f16: tensors of 2 or more dimensions with at least
# F16_MIN_VALUES values (the weight matrices, convolutions, embeddings, heads and codebooks: 98.6% of the
# default model's f32 bytes) whose values all stay finite in binary16 (|x| < 65520). Kept in f32, bit-exact:
# every 1-D tensor and small matrix (0.14 MB in the default model: f16 would save almost nothing there), and
# by name the tensors where a relative error of 2^-11 is not worth 0.1 MB: the Mamba dynamics
# (A = -exp(A_log) and the step size dt = softplus(dt_proj ...) are exponentiated or compounded over every
# step, D is a skip gain), the input/output normalisation statistics (music_mean/std, pose_mean/std: they
# scale raw features and the decoded poses), norms, biases and the folded BatchNorm.
F16_MIN_VALUES = 4096
F16_KEEP_F32 = ("*.A_log", "*.D", "*dt_proj*", "seq.music_mean", "seq.music_std", "*pose_mean", "*pose_std",
                "*norm*", "*bias", "*bn_scale", "*bn_shift", "*conv_b")


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


def _fits_f16(a: np.ndarray) -> bool:
  with np.errstate(over="ignore"):
    return bool(np.all(np.isfinite(a.astype(np.float16))))


def f16_policy(tensors: Mapping[str, np.ndarray]) -> dict[str, str]:
  """The file dtype ("f16" or "f32") of each tensor under the shipped models' policy (F16_KEEP_F32 above)."""
  out = {}
  for name, arr in tensors.items():
    a = np.asarray(arr, dtype=np.float32)
    keep = (a.ndim < 2 or a.size < F16_MIN_VALUES or any(fnmatch.fnmatchcase(name, p) for p in F16_KEEP_F32)
            or not _fits_f16(a))
    out[name] = "f32" if keep else "f16"
  return out


def write_dncw(path: str, tensors: dict[str, np.ndarray], metadata: dict,
               dtypes: Mapping[str, str] | None = None) -> None:
  """Writes `tensors` with their file dtypes: `dtypes[name]` ("f32" or "f16", e.g. from f16_policy) where
  given, else "f16" for a numpy float16 array and "f32" for anything else. f16 rounds to nearest even; a value
  that does not fit (|x| >= 65520) is an error, like NaN or Inf in any dtype."""
  dtypes = dtypes or {}
  entries, blobs, offset = [], [], 0
  for name, arr in tensors.items():
    dtype = dtypes.get(name, "f16" if np.asarray(arr).dtype == np.float16 else "f32")
    if dtype not in DTYPES:
      raise ValueError(f"tensor {name}: dtype {dtype!r} unsupported (supported: {', '.join(DTYPES)})")
    a = np.ascontiguousarray(arr, dtype="<f4")
    if not np.all(np.isfinite(a)):
      raise ValueError(f"tensor {name} has NaN or Inf")
    if dtype == "f16":
      if not _fits_f16(a):
        raise ValueError(f"tensor {name} does not fit in f16 (max |x| {np.abs(a).max():g} would round to Inf: >= 65520)")
      a = a.astype(DTYPES["f16"])
    raw = a.tobytes()
    entries.append({"name": name, "dtype": dtype, "shape": list(a.shape), "offset": offset,
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
  """Returns (header JSON, tensors), checking every field the engine checks. Tensors are float32 whatever
  their file dtype (f16 values widened exactly); the header's "tensors" entries give each one's dtype."""
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
    if e["dtype"] not in DTYPES:
      raise ValueError(f"tensor {e['name']}: dtype {e['dtype']!r} unsupported (supported: {', '.join(DTYPES)})")
    dtype = DTYPES[e["dtype"]]
    if e["offset"] % ALIGN or start + e["nbytes"] > len(buf) - 4:
      raise ValueError(f"bad tensor entry {e['name']}")
    if e["nbytes"] != dtype.itemsize * int(np.prod(e["shape"])):
      raise ValueError(f"nbytes mismatch for {e['name']}")
    raw = buf[start:start + e["nbytes"]]
    if zlib.crc32(raw) != e["crc32"]:
      raise ValueError(f"CRC mismatch for {e['name']}")
    a = np.frombuffer(raw, dtype=dtype).reshape(e["shape"]).astype(np.float32)
    if not np.all(np.isfinite(a)):
      raise ValueError(f"tensor {e['name']} has NaN or Inf")
    tensors[e["name"]] = a
  return header, tensors


def convert_dncw(src: str, dst: str, dtype: str = "f16") -> dict[str, str]:
  """Rewrites `src` as `dst` with the same header metadata and tensor order: "f16" stores the tensors
  f16_policy picks as f16 (the others stay bit-exact), "f32" stores everything as f32 (f16 values exactly).
  Returns the dtypes written. `src` and `dst` may be the same path."""
  if dtype not in DTYPES:
    raise ValueError(f"dtype {dtype!r} unsupported (supported: {', '.join(DTYPES)})")
  header, tensors = read_dncw(src)
  dtypes = f16_policy(tensors) if dtype == "f16" else {name: "f32" for name in tensors}
  write_dncw(dst, tensors, header.get("metadata", {}), dtypes)
  return dtypes


def set_metadata(path: str, assignments: Mapping[str, object]) -> dict:
  """Rewrites `path` in place with metadata fields set ("a.b" = nested key; dicts are created on the way),
  tensors and their dtypes bit-exact. Returns the new metadata."""
  header, tensors = read_dncw(path)
  meta = header.get("metadata", {})
  for key, value in assignments.items():
    node = meta
    *parents, leaf = key.split(".")
    for k in parents:
      node = node.setdefault(k, {})
      if not isinstance(node, dict):
        raise ValueError(f"metadata {key}: {k} is not an object")
    node[leaf] = value
  _rewrite(path, tensors, meta, {e["name"]: e["dtype"] for e in header["tensors"]})
  return meta


def _rewrite(path: str, tensors: dict[str, np.ndarray], meta: dict, dtypes: Mapping[str, str]) -> None:
  """write_dncw to a temporary file, then over `path`: a failed write leaves the original file intact."""
  tmp = f"{path}.tmp"
  write_dncw(tmp, tensors, meta, dtypes)
  os.replace(tmp, path)


def graft_tensors(path: str, src: str, prefixes: list[str]) -> list[str]:
  """Rewrites `path` in place with every tensor whose name starts with one of `prefixes` taken from `src`
  (names, shapes and dtypes must match: the same architecture), the other tensors and the metadata
  bit-exact; records the graft under metadata training.grafted. Returns the names replaced. E.g. one
  VQ-VAE's decoder, fine-tuned by training.experiments.vq_decoder from an older file, into the shipped model."""
  header, tensors = read_dncw(path)
  src_header, src_tensors = read_dncw(src)
  src_dtypes = {e["name"]: e["dtype"] for e in src_header["tensors"]}
  dtypes = {e["name"]: e["dtype"] for e in header["tensors"]}
  names = [n for n in tensors if any(n.startswith(p) for p in prefixes)]
  if not names:
    raise ValueError(f"no tensor of {path} starts with {', '.join(prefixes)}")
  for n in names:
    if n not in src_tensors:
      raise ValueError(f"{src} has no tensor {n}")
    if src_tensors[n].shape != tensors[n].shape or src_dtypes[n] != dtypes[n]:
      raise ValueError(f"{n}: {src} has {src_dtypes[n]} {list(src_tensors[n].shape)}, {path} has "
                       f"{dtypes[n]} {list(tensors[n].shape)}")
    tensors[n] = src_tensors[n]
  meta = header.get("metadata", {})
  meta.setdefault("training", {}).setdefault("grafted", []).append(
      {"prefixes": list(prefixes), "tensors": len(names), "from_model_id": src_header["metadata"].get("model_id")})
  _rewrite(path, tensors, meta, dtypes)
  return names


def dtype_summary(header: dict) -> str:
  """Tensor count and stored bytes per dtype of a header's tensor entries, e.g. "f16: 180 tensors ..."."""
  count, size = {}, {}
  for e in header["tensors"]:
    count[e["dtype"]] = count.get(e["dtype"], 0) + 1
    size[e["dtype"]] = size.get(e["dtype"], 0) + e["nbytes"]
  return ", ".join(f"{d}: {count[d]} tensors {size[d] / 1e6:.2f} MB" for d in sorted(count))


def export_model(path: str, model: Danceba, vqs: dict[str, PoseVQVAE], extra: dict,
                 weights_dtype: str = "f16") -> dict:
  """Writes model + both VQ-VAEs to `path`; returns the metadata written. weights_dtype "f16" applies
  f16_policy (the shipped models' format), "f32" stores every tensor as f32."""
  tensors = seq_tensors(model)
  for part in PARTS:
    tensors.update(vq_tensors(part, vqs[part])[0])
  meta = build_metadata(model, vqs, extra)
  if weights_dtype not in DTYPES:
    raise ValueError(f"weights_dtype {weights_dtype!r} unsupported (supported: {', '.join(DTYPES)})")
  write_dncw(path, tensors, meta, f16_policy(tensors) if weights_dtype == "f16" else None)
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


def change_summary(before: Mapping[str, np.ndarray], after: Mapping[str, np.ndarray]) -> str:
  """How much the values of `after` differ from those of `before` (same names and shapes): max absolute
  change; max relative change over the values in binary16's normal range (|x| >= 2^-14, where f16 rounding
  is within 2^-11 relative; smaller values keep an absolute error <= 2^-25); values that became 0."""
  max_abs = max_rel = 0.0
  zeroed = 0
  for name, b in before.items():
    a = after[name]
    diff = np.abs(a.astype(np.float64) - b)
    max_abs = max(max_abs, float(diff.max(initial=0.0)))
    normal = np.abs(b) >= 2.0 ** -14
    max_rel = max(max_rel, float((diff[normal] / np.abs(b[normal])).max(initial=0.0)))
    zeroed += int(np.count_nonzero((a == 0) & (b != 0)))
  return f"max |change| {max_abs:.3g}, max relative change {max_rel:.3g} (|x| >= 2^-14), {zeroed} values -> 0"


def main(argv: list[str] | None = None) -> None:
  ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  ap.add_argument("--check", metavar="FILE", help="read a .dncw file, validate it and print a summary")
  ap.add_argument("--convert", nargs=2, metavar=("IN", "OUT"),
                  help="rewrite IN as OUT with the tensor dtypes of --dtype (metadata unchanged), then check OUT")
  ap.add_argument("--dtype", choices=sorted(DTYPES), default="f16",
                  help="for --convert: f16 = the f16 policy (docs/weights-format.md), f32 = every tensor f32")
  ap.add_argument("--set-meta", nargs="+", metavar=("FILE", "KEY=JSON"),
                  help="rewrite FILE in place with metadata KEY (a.b for nested) set to the JSON value, tensors "
                       "bit-exact; e.g. --set-meta models/default.dncw sampling.guidance=3")
  ap.add_argument("--graft", nargs="+", metavar=("FILE", "SRC"),
                  help="FILE SRC PREFIX [PREFIX ...]: rewrite FILE in place with the tensors whose names start "
                       "with a PREFIX taken from SRC (same shapes and dtypes), everything else bit-exact; e.g. "
                       "--graft models/default.dncw tuned.dncw vq.upper.dec.")
  args = ap.parse_args(argv)
  if not args.check and not args.convert and not args.set_meta and not args.graft:
    ap.error("nothing to do: give --check FILE, --convert IN OUT, --set-meta FILE KEY=JSON ... or --graft FILE SRC "
             "PREFIX ...")
  try:
    _run(args, ap)
  except (OSError, ValueError) as e:  # a missing or bad file, a bad key or prefix: one line, exit status 1
    ap.exit(1, f"training.export: {e}\n")


def _run(args, ap: argparse.ArgumentParser) -> None:
  if args.graft:
    if len(args.graft) < 3:
      ap.error("--graft FILE SRC PREFIX [PREFIX ...]")
    path, src, *prefixes = args.graft
    before = read_dncw(path)[1]
    names = graft_tensors(path, src, prefixes)
    print(f"{path}: {len(names)} tensors from {src}; {change_summary(before, read_dncw(path)[1])}")
    args.check = args.check or path
  if args.set_meta:
    path, *pairs = args.set_meta
    if not pairs or any("=" not in p for p in pairs):
      ap.error("--set-meta FILE KEY=JSON [KEY=JSON ...]")
    before = read_dncw(path)[1]
    set_metadata(path, {k: json.loads(v) for k, v in (p.split("=", 1) for p in pairs)})
    print(f"{path}: set {', '.join(pairs)}; {change_summary(before, read_dncw(path)[1])}")
    args.check = args.check or path
  if args.convert:
    src, dst = args.convert
    with open(src, "rb") as f:
      size_in = len(f.read())
    before = read_dncw(src)[1]
    convert_dncw(src, dst, args.dtype)
    with open(dst, "rb") as f:
      size_out = len(f.read())
    print(f"{src} ({size_in} bytes) -> {dst} ({size_out} bytes, {size_out / size_in:.1%}); "
          f"{change_summary(before, read_dncw(dst)[1])}")
  path = args.check or args.convert[1]
  header, t = read_dncw(path)
  n = sum(a.size for a in t.values())
  print(f"{path}: {len(t)} tensors, {n} parameters, model_id={header['metadata']['model_id']}; "
        f"{dtype_summary(header)}")


if __name__ == "__main__":
  main()
