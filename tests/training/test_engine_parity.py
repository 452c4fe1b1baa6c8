"""The engine against the same model in PyTorch, free-running (training.eval.engine_parity): the codes
`dance-generate` samples over a real song equal the PyTorch model's, drawn with a transcription of the
engine's sampler, step for step, with style guidance and with the music-mean lanes of music guidance."""
from __future__ import annotations

import json

import numpy as np
import pytest

from training import tools
from training.data import skeleton as sk
from training.experiments.free_run import decode_codes
from training.eval import engine_parity as ep
from training.export import load_models

MODEL = "models/default.dncw"
STEPS = 160  # 21 s of dance


def test_mt19937_64_is_the_standard_generator():
  # C++ [rand.predef]: the 10000th output of a default-constructed std::mt19937_64 (seed 5489).
  g = ep.Mt19937_64(5489)
  for _ in range(9999):
    g()
  assert g() == 9981545732273789042


def test_sampler_follows_the_inverse_cdf():
  # Three codes with probabilities 0.5, 0.3, 0.2 (index 2 most likely first); the draw u picks the code whose
  # cumulative interval (in descending probability) holds u.
  logits = np.log(np.array([0.3, 0.2, 0.5], np.float32))
  s = ep.EngineSampler(0)
  u_of = ep.Mt19937_64(0)
  for _ in range(200):
    u = float(u_of() >> 11) * 2.0 ** -53
    want = 2 if u < 0.5 else (0 if u < 0.8 else 1)
    assert s(logits) == want
  assert ep.EngineSampler(0, temperature=0.0)(logits) == 2


@pytest.fixture(scope="module")
def song(shared_data_dir):
  path = shared_data_dir / "tang2018" / "DANCE_C_6" / "audio.ogg"
  if not path.is_file():
    pytest.skip(f"no song at {path}")
  try:
    tools.require("dance-generate")
  except tools.ToolMissing as e:
    pytest.skip(str(e))
  return str(path)


@pytest.fixture(scope="module")
def model():
  m, _, meta = load_models(MODEL)  # (torch_free_run and decode_codes run under no_grad: no global switch)
  return m, meta


@pytest.mark.parametrize("guidance,music_guidance", [(3.0, 1.0), (3.0, 0.0)])
def test_free_running_codes_equal_the_engines(song, model, tmp_path, features_cli, guidance, music_guidance):
  m, meta = model
  ref = meta["time_base"]["style_reference_bpm"]["cha-cha"]
  music, pre = ep.song_tokens(song, ref, cache_dir=tmp_path / "features")
  ours = ep.torch_free_run(m, music, pre, meta["styles"].index("cha-cha"), seed=7, guidance=guidance,
                           music_guidance=music_guidance, steps=STEPS)
  theirs = ep.engine_codes(MODEL, song, "cha-cha", 7, tmp_path, guidance=guidance, music_guidance=music_guidance)
  assert np.abs(ep.engine_tokens(tmp_path, "song", 7)[:STEPS] - music[:STEPS]).max() < 1e-6  # the same inputs
  row = ep.compare(ours, theirs[:STEPS])
  assert row["steps"] == STEPS
  assert row["first_diff"] == STEPS, row
  # The comparison can fail: another seed parts within a few steps.
  other = ep.torch_free_run(m, music, pre, meta["styles"].index("cha-cha"), seed=8, guidance=guidance,
                            music_guidance=music_guidance, steps=20)
  assert ep.compare(other, theirs[:20])["first_diff"] < 10


def test_engine_dance_is_the_models_decode_retimed(song, model, tmp_path, features_cli):
  # The whole song's real-time dance (foot lock off) equals the PyTorch VQ decoders on the engine's codes,
  # played back on the real timeline through the tempo clock: the decode, root integration and retiming
  # agree to float rounding (W_m from `dance-features --clock-starts`); the last frame, past the decoded
  # poses' end, is left out.
  m, meta = model
  _, vqs, _ = load_models(MODEL)
  codes = ep.engine_codes(MODEL, song, "cha-cha", 3, tmp_path, name="c6")
  tools.dance_generate_summary(MODEL, song, tmp_path / "raw.json", seed=3, style="cha-cha",
                               extra=["--period-lock", 0, "--crouch-guard", 0, "--foot-lock", 0])
  d = json.loads((tmp_path / "raw.json").read_text())
  theirs = np.asarray(d["positions"], np.float64).reshape(-1, 24, 3)
  skel = sk.load_skeleton()
  decoded = decode_codes(vqs, codes[:, 0], codes[:, 1], "c6", skel).positions.astype(np.float64)
  starts = ep.clock_starts(song, meta["time_base"]["style_reference_bpm"]["cha-cha"], tmp_path / "clock")
  ours = ep.retime_to_real(decoded, starts, d["frame_index0"], len(theirs), skel)[:-1]
  assert len(ours) > 0.99 * len(theirs)
  err = np.linalg.norm(ours - theirs[:len(ours)], axis=-1)
  assert np.median(err) < 1e-4 and err.max() < 1e-3, (np.median(err), err.max())
  # And it can fail: the dance of another seed is far off.
  other = ep.engine_codes(MODEL, song, "cha-cha", 4, tmp_path, name="c6")
  wrong = decode_codes(vqs, other[:, 0], other[:, 1], "c6", skel).positions.astype(np.float64)
  far = ep.retime_to_real(wrong, starts, d["frame_index0"], len(theirs), skel)[:-1]
  assert np.median(np.linalg.norm(far - theirs[:len(far)], axis=-1)) > 0.05
