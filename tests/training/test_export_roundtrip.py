"""The .dncw writer and reader round-trip, and reject corrupt files; the committed tiny model loads."""
import json
import pathlib
import struct

import numpy as np
import pytest
import torch

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
