"""The .dncw writer and reader round-trip, and reject corrupt files; the committed tiny model loads."""
import json
import os
import pathlib
import struct
import subprocess
import sys
import zlib

import numpy as np
import pytest
import torch

from training import export
from training.export import export_model, load_models, read_dncw, seq_tensors, write_dncw
from training.model import PoseVQVAE, SeqConfig, VQConfig
from training.model.danceba import Danceba

REPO = pathlib.Path(__file__).resolve().parents[2]


def _tiny():
  torch.manual_seed(0)
  model = Danceba(SeqConfig(feature_dim=6, pre_dim=8, d_model=16, n_heads=2, codebook_size=8, n_styles=2,
                            style_dim=4)).eval()
  with torch.no_grad():
    model.pre.bn.running_mean.normal_()
    model.pre.bn.running_var.uniform_(0.5, 2.0)
  vqs = {p: PoseVQVAE(VQConfig(in_dim=d, width=8, code_dim=4, codebook_size=8)).eval()
         for p, d in (("upper", 45), ("lower", 31))}
  return model, vqs


def test_roundtrip_same_outputs(tmp_path):
  model, vqs = _tiny()
  path = tmp_path / "m.dncw"
  export_model(str(path), model, vqs, {"model_id": "t", "styles": ["a", "b"]})
  header, tensors = read_dncw(str(path))
  assert header["format"] == "dance-weights" and header["version"] == 1
  for e in header["tensors"]:
    assert e["offset"] % 64 == 0
  model2, vqs2, meta = load_models(str(path))
  assert meta["styles"] == ["a", "b"]
  ops = meta["vq"]["lower"]["decoder_ops"]
  assert ops[0] == {"op": "embed_codes"} and all(o["w"] in tensors for o in ops if o["op"] == "conv")
  b, t = 1, 5
  args = (torch.randn(b, t, 24), torch.rand(b, t, 8), torch.randint(0, 9, (b, t)), torch.randint(0, 9, (b, t)),
          torch.tensor([[0.0, 1.0, 0.0]]))
  for a, c in zip(model(*args), model2(*args)):
    torch.testing.assert_close(a, c, atol=1e-5, rtol=1e-5)
  codes = torch.randint(0, 8, (1, 4))
  torch.testing.assert_close(vqs["lower"].decode_codes(codes), vqs2["lower"].decode_codes(codes))


def test_corruption_is_detected(tmp_path):
  path = tmp_path / "x.dncw"
  write_dncw(str(path), {"a": np.arange(6, dtype=np.float32).reshape(2, 3)}, {"model_id": "x"})
  raw = bytearray(path.read_bytes())
  header, t = read_dncw(str(path))
  np.testing.assert_array_equal(t["a"], np.arange(6).reshape(2, 3))
  raw[-10] ^= 0xFF
  path.write_bytes(bytes(raw))
  with pytest.raises(ValueError, match="CRC"):
    read_dncw(str(path))
  with pytest.raises(ValueError, match="NaN"):
    write_dncw(str(tmp_path / "n.dncw"), {"a": np.array([np.nan], np.float32)}, {})


def test_header_layout(tmp_path):
  path = tmp_path / "h.dncw"
  write_dncw(str(path), {"w": np.ones((3,), np.float32)}, {"model_id": "h"})
  raw = path.read_bytes()
  assert raw[:4] == b"DNCW"
  version, hlen = struct.unpack_from("<IQ", raw, 4)
  assert version == 1
  assert json.loads(raw[16:16 + hlen])["tensors"][0]["shape"] == [3]


@pytest.mark.parametrize("name", ["test-tiny", "default"])
def test_committed_model_matches_its_fixtures(name):
  path = REPO / "models" / f"{name}.dncw"
  golden = REPO / "tests" / "golden" / name
  if name == "default" and not path.is_file():
    pytest.skip("no default model exported")
  model, vqs, meta = load_models(str(path))
  assert set(seq_tensors(model)) <= set(read_dncw(str(path))[1])
  index = json.loads((golden / "index.json").read_text())
  feats = np.load(golden / "input_features.npy")
  pre = np.load(golden / "input_pre.npy")
  style = torch.from_numpy(np.load(golden / "input_style.npy"))[None]
  k = model.cfg.codebook_size
  u = l = torch.tensor([k])
  state, codes = None, []
  n = 32
  music = torch.from_numpy(feats.reshape(index["steps"], -1))
  with torch.no_grad():
    for t in range(n):
      lu, ll, state = model.step(music[t:t + 1], torch.from_numpy(pre[4 * t + 3])[None], u, l, style, state)
      u, l = lu.argmax(-1), ll.argmax(-1)
      codes.append(int(u))
  np.testing.assert_array_equal(codes, np.load(golden / "greedy_codes_upper.npy")[:n])


# ---- f16 tensors ----------------------------------------------------------------------------------------
HALF_VALUES = np.array([0.0, -0.0, 2.0 ** -24, -2.0 ** -24, 1023 * 2.0 ** -24, 2.0 ** -14, 65504.0, -65504.0, 1.0,
                        0.1, -3.14159, 1234.5], np.float32)  # zero, -0, subnormals, min/max normal, rounded ones


def _bits(a: np.ndarray) -> np.ndarray:
  return np.ascontiguousarray(a, np.float32).view(np.uint32)


def test_f16_roundtrip(tmp_path):
  path = tmp_path / "h.dncw"
  w = HALF_VALUES.reshape(6, 2)
  write_dncw(str(path), {"h": w, "n": HALF_VALUES.astype(np.float16), "f": w}, {"model_id": "h"},
             dtypes={"h": "f16"})  # "n" is f16 because it is a float16 array, "f" stays f32
  header, t = read_dncw(str(path))
  entries = {e["name"]: e for e in header["tensors"]}
  assert [entries[n]["dtype"] for n in ("h", "n", "f")] == ["f16", "f16", "f32"]
  assert entries["h"]["nbytes"] == 2 * w.size and entries["f"]["nbytes"] == 4 * w.size
  assert all(a.dtype == np.float32 for a in t.values())
  expected = w.astype(np.float16).astype(np.float32)
  np.testing.assert_array_equal(_bits(t["h"]), _bits(expected))  # -0 keeps its sign, subnormals exact
  np.testing.assert_array_equal(_bits(t["n"]), _bits(expected.ravel()))
  np.testing.assert_array_equal(_bits(t["f"]), _bits(w))
  assert t["h"][0, 1] == 0 and np.signbit(t["h"][0, 1]) and t["h"][1, 0] == 2.0 ** -24
  assert t["h"][4, 1] == np.float32(np.float16(0.1)) != np.float32(0.1)
  raw = bytearray(path.read_bytes())
  hlen = struct.unpack_from("<Q", raw, 8)[0]
  data = 16 + hlen + (-(16 + hlen)) % 64
  assert raw[data + 12:data + 14] == b"\xff\x7b"  # 65504 = 0x7BFF, little-endian
  with pytest.raises(ValueError, match="does not fit in f16"):
    write_dncw(str(tmp_path / "o.dncw"), {"o": np.array([70000.0], np.float32)}, {}, dtypes={"o": "f16"})
  with pytest.raises(ValueError, match="unsupported"):
    write_dncw(str(tmp_path / "b.dncw"), {"o": np.ones(2, np.float32)}, {}, dtypes={"o": "bf16"})


def test_f16_policy_picks_big_matrices_only():
  rng = np.random.default_rng(0)
  big = rng.standard_normal((128, 64)).astype(np.float32)
  tensors = {"seq.head.upper": big, "vq.upper.dec.conv1.weight": rng.standard_normal((32, 64, 3)),
             "vq.upper.codebook": big * 30, "seq.pmmm.0.music.mamba.A_log": big,
             "seq.pmmm.0.music.mamba.D": big, "seq.pmmm.0.music.mamba.dt_proj.weight": big,
             "seq.music_mean": big, "vq.lower.pose_std": big, "seq.norm_f.weight": big,
             "seq.pre.bn_scale": big, "seq.embed.music.bias": big, "seq.embed.stream": big[:3],
             "seq.final.w_q": np.full((128, 64), 7e4, np.float32), "x.vector": rng.standard_normal(10000)}
  dtypes = export.f16_policy(tensors)
  f16 = {n for n, d in dtypes.items() if d == "f16"}
  assert f16 == {"seq.head.upper", "vq.upper.dec.conv1.weight", "vq.upper.codebook"}
  assert set(dtypes) == set(tensors) and set(dtypes.values()) == {"f16", "f32"}


def _run_export(*args: str) -> str:
  proc = subprocess.run([sys.executable, "-m", "training.export", *args], cwd=REPO, capture_output=True,
                        text=True, env=dict(os.environ, OMP_WAIT_POLICY="PASSIVE"), check=True)
  return proc.stdout


def test_convert_keeps_values_within_f16_rounding_and_sensitive_ones_exact(tmp_path):
  src = REPO / "models" / "test-tiny.dncw"
  out, back = tmp_path / "tiny-f16.dncw", tmp_path / "tiny-f32.dncw"
  report = _run_export("--convert", str(src), str(out), "--dtype", "f16")
  assert "max relative change" in report and "f16: " in report and "f32: " in report
  h0, t0 = read_dncw(str(src))
  h1, t1 = read_dncw(str(out))
  assert h1["metadata"] == h0["metadata"]
  assert [e["name"] for e in h1["tensors"]] == [e["name"] for e in h0["tensors"]]
  assert all(e["dtype"] == "f32" for e in h0["tensors"])
  dtypes = {e["name"]: e["dtype"] for e in h1["tensors"]}
  assert dtypes == export.f16_policy(t0) and "f16" in dtypes.values()
  assert out.stat().st_size < src.stat().st_size
  for name, a in t0.items():
    b = t1[name]
    assert b.shape == a.shape and b.dtype == np.float32
    if dtypes[name] == "f16":
      np.testing.assert_array_equal(b, a.astype(np.float16).astype(np.float32), err_msg=name)
      assert np.all(np.abs(b - a) <= np.maximum(np.abs(a) * 2.0 ** -11, 2.0 ** -25)), name
    else:
      np.testing.assert_array_equal(_bits(b), _bits(a), err_msg=name)
    sensitive = a.ndim < 2 or any(s in name for s in ("A_log", "mamba.D", "dt_proj", "music_mean", "music_std",
                                                      "pose_mean", "pose_std", "norm", "bias", "bn_s"))
    assert not sensitive or dtypes[name] == "f32", name
  load_models(str(out))  # the torch side loads it too
  # Back to all-f32: the f16 values exactly; --check reports the dtypes.
  _run_export("--convert", str(out), str(back), "--dtype", "f32")
  h2, t2 = read_dncw(str(back))
  assert all(e["dtype"] == "f32" for e in h2["tensors"])
  for name in t1:
    np.testing.assert_array_equal(_bits(t2[name]), _bits(t1[name]))
  check = _run_export("--check", str(out))
  assert "model_id=test-tiny" in check and "f16: " in check and "f32: " in check


def test_read_refuses_unknown_dtype_and_f16_nbytes(tmp_path):
  path = tmp_path / "h.dncw"
  write_dncw(str(path), {"h": np.ones((2, 2), np.float32)}, {}, dtypes={"h": "f16"})
  raw = path.read_bytes()

  def patched(old: bytes, new: bytes) -> pathlib.Path:
    body = raw[:-4].replace(old, new)
    p = tmp_path / "p.dncw"
    p.write_bytes(body + struct.pack("<I", zlib.crc32(body)))
    return p

  with pytest.raises(ValueError, match="unsupported"):
    read_dncw(str(patched(b'"f16"', b'"i16"')))
  with pytest.raises(ValueError, match="nbytes"):
    read_dncw(str(patched(b'"nbytes":8', b'"nbytes":4')))


def test_set_meta_changes_only_the_named_fields(tmp_path):
  src = REPO / "models" / "test-tiny.dncw"
  path = tmp_path / "tiny.dncw"
  _run_export("--convert", str(src), str(path), "--dtype", "f16")
  h0, t0 = read_dncw(str(path))
  report = _run_export("--set-meta", str(path), "sampling.guidance=3", 'model_id="tiny-2"')
  assert "sampling.guidance=3" in report and "model_id=tiny-2" in report
  h1, t1 = read_dncw(str(path))
  want = json.loads(json.dumps(h0["metadata"]))
  want["sampling"] = {"guidance": 3}
  want["model_id"] = "tiny-2"
  assert h1["metadata"] == want
  assert [(e["name"], e["dtype"]) for e in h1["tensors"]] == [(e["name"], e["dtype"]) for e in h0["tensors"]]
  for name, a in t0.items():
    np.testing.assert_array_equal(_bits(t1[name]), _bits(a), err_msg=name)
  with pytest.raises(subprocess.CalledProcessError):
    _run_export("--set-meta", str(path), "sampling.guidance")   # no value


def test_graft_replaces_only_the_prefixed_tensors(tmp_path):
  src = REPO / "models" / "test-tiny.dncw"
  a, b = tmp_path / "a.dncw", tmp_path / "b.dncw"
  _run_export("--convert", str(src), str(a), "--dtype", "f16")
  _run_export("--convert", str(src), str(b), "--dtype", "f16")
  hb, tb = read_dncw(str(b))
  dec = [n for n in tb if n.startswith("vq.upper.dec.")]
  assert dec
  # b: the upper decoder changed (as a fine-tuning would), everything else as a
  changed = {n: (t + 0.5).astype(t.dtype) if n in dec else t for n, t in tb.items()}
  write_dncw(str(b), changed, hb["metadata"], {e["name"]: e["dtype"] for e in hb["tensors"]})
  changed = read_dncw(str(b))[1]  # as stored (f16 tensors rounded)
  h0, t0 = read_dncw(str(a))
  report = _run_export("--graft", str(a), str(b), "vq.upper.dec.")
  assert f"{len(dec)} tensors from" in report
  h1, t1 = read_dncw(str(a))
  for name, t in t0.items():
    want = changed[name] if name in dec else t
    np.testing.assert_array_equal(_bits(t1[name]), _bits(want), err_msg=name)
  assert [(e["name"], e["dtype"]) for e in h1["tensors"]] == [(e["name"], e["dtype"]) for e in h0["tensors"]]
  assert h1["metadata"]["training"]["grafted"][-1]["prefixes"] == ["vq.upper.dec."]
  with pytest.raises(subprocess.CalledProcessError):
    _run_export("--graft", str(a), str(b), "no.such.prefix")
  # A missing source file is a one-line error, not a traceback, and leaves the target as it was.
  with pytest.raises(subprocess.CalledProcessError) as e:
    _run_export("--graft", str(a), str(tmp_path / "missing.dncw"), "vq.upper.dec.")
  assert e.value.returncode == 1 and "Traceback" not in e.value.stderr and "missing.dncw" in e.value.stderr
  np.testing.assert_array_equal(_bits(read_dncw(str(a))[1][dec[0]]), _bits(changed[dec[0]]))
