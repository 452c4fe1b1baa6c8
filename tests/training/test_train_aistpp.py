"""Training on AIST++ (../shared/data/MANIFEST.md: "A user who has it must be able to train on it"): a dance
written in the AIST++ layout goes through the loader, the motion cache, the music features and tokens into
a sequence-model step that trains its genre's style row; the shipped style rows stay as they are."""
import pickle
import wave

import numpy as np
import pytest
import torch

from training.common import clips as td
from training.data import aistpp, prepare
from training.data.skeleton import J, load_skeleton
from training.model import SeqConfig, VQConfig
from training.model.danceba import Danceba
from training.model.vqvae import PoseVQVAE
from training.common.seq_loss import loss_of
from training.common.tokens import make_batch, tokenize

BPM, SECONDS, SR = 120.0, 20.0, 24000


def _cache(tmp_path, monkeypatch, labels: dict[str, tuple[str, str]]):
  """A motion cache holding one short dance per id: {id: (style, audio_path)}."""
  cache = tmp_path / "motion"
  cache.mkdir()
  monkeypatch.setattr(td, "MOTION_CACHE", cache)
  pos = np.repeat(load_skeleton().rest_positions()[None], 8, 0).astype(np.float32)
  for i, (style, audio) in labels.items():
    np.savez(cache / f"{i}.npz", positions=pos, style=style, audio_path=audio, audio_offset_s=0.0)


def test_style_rows_keep_the_shipped_layout_and_append_aists_genres(tmp_path, monkeypatch):
  assert td.ALL_STYLES[:len(td.STYLES)] == td.STYLES
  assert set(td.ALL_STYLES) == set(td.STYLES) | set(aistpp.AIST_GENRES.values())
  assert len(set(td.ALL_STYLES)) == len(td.ALL_STYLES)
  _cache(tmp_path, monkeypatch, {"tang_DANCE_W_1": ("waltz", "w.ogg"), "cmu_salsa_1": ("salsa", ""),
                                 "aist_gBR_x": ("break", "b.wav"), "odd": ("tap", "t.wav")})
  assert td.styles_for(["tang_DANCE_W_1", "cmu_salsa_1"]) == td.STYLES
  assert td.styles_for(["tang_DANCE_W_1", "aist_gBR_x"]) == td.ALL_STYLES
  assert td.style_index("break") == len(td.STYLES) and td.style_index("waltz") == td.STYLES.index("waltz")
  with pytest.raises(ValueError, match="unknown style label 'tap'"):
    td.styles_for(["odd"])


def test_paired_ids_are_the_dances_with_music(tmp_path, monkeypatch):
  _cache(tmp_path, monkeypatch, {"cmu_salsa_1": ("salsa", ""), "aist_gBR_x": ("break", "b.wav")})
  ids = ["tang_DANCE_W_1", "cmu_salsa_1", "aist_gBR_x", "aist_not_converted"]
  assert td.paired_ids(ids) == ["tang_DANCE_W_1", "aist_gBR_x"]
  assert td.tang_ids(ids) == ["tang_DANCE_W_1"]


def _click_wav(path):
  t = np.arange(int(SECONDS * SR)) / SR
  x = np.zeros_like(t)
  for k, b in enumerate(np.arange(0.25, SECONDS, 60.0 / BPM)):
    i, n = int(b * SR), int(0.05 * SR)
    x[i:i + n] += (1.0 if k % 4 == 0 else 0.6) * np.sin(2 * np.pi * 1000 * t[:n]) * np.exp(-t[:n] / 0.01)
  with wave.open(str(path), "wb") as w:
    w.setnchannels(1)
    w.setsampwidth(2)
    w.setframerate(SR)
    w.writeframes((np.clip(x, -1, 1) * 0.5 * 32767).astype(np.int16).tobytes())


def test_an_aistpp_dance_trains_its_genres_style_row(tmp_path, monkeypatch, features_cli):
  root = tmp_path / "aist"
  (root / "motions").mkdir(parents=True)
  (root / "wavs").mkdir()
  _click_wav(root / "wavs" / "mBR0.wav")
  t = int(SECONDS * 60)
  poses = np.zeros((t, 72))                        # 60 fps; knees bend once per beat, arms swing
  beat = np.sin(2 * np.pi * np.arange(t) / 60.0 * BPM / 60.0)
  poses[:, 3 * J["left_knee"]] = 0.4 * (1 + beat)
  poses[:, 3 * J["right_knee"]] = 0.4 * (1 - beat)
  poses[:, 3 * J["left_shoulder"] + 2] = 0.8 * beat
  trans = np.stack([0.3 * np.sin(np.arange(t) / 60.0), np.full(t, 0.9), np.zeros(t)], -1)
  with open(root / "motions" / "gBR_sBM_cAll_d04_mBR0_ch01.pkl", "wb") as f:
    pickle.dump({"smpl_poses": poses, "smpl_trans": trans, "smpl_scaling": np.array([1.0])}, f)
  for name in ("MOTION_CACHE", "FEATURE_CACHE", "STRETCH_CACHE"):
    (tmp_path / name).mkdir()
    monkeypatch.setattr(td, name, tmp_path / name)
  [(mid, motion)] = list(aistpp.load_aistpp(root))
  prepare._save(td.MOTION_CACHE / f"{mid}.npz", motion)

  assert td.paired_ids([mid]) == [mid] and td.styles_for([mid]) == td.ALL_STYLES
  clip = td.load_clip(mid)
  assert clip.style == td.style_index("break")
  assert clip.features.shape == (len(clip.upper), 108) and abs(len(clip.upper) - SECONDS * 30) <= 2
  refs = td.style_reference_tempi([mid], 105.0)
  assert abs(refs["break"] - BPM) < 3 and refs["waltz"] == 105.0 and "krump" not in refs
  rows = td.style_reference_tempi([mid], 105.0, td.ALL_STYLES)   # a run's rows: every one gets a reference
  assert list(rows) == td.ALL_STYLES and rows["krump"] == 105.0 and rows["break"] == refs["break"]

  torch.manual_seed(0)
  vqs = {part: PoseVQVAE(VQConfig(in_dim=dim, width=16, code_dim=8, codebook_size=16, n_res=1))
         for part, dim in (("upper", 45), ("lower", 31))}
  tok = tokenize(clip, vqs)
  cfg = SeqConfig(feature_dim=108, pre_dim=128, d_model=16, n_heads=2, codebook_size=16,
                  n_styles=len(td.ALL_STYLES), style_dim=4, attn_window=8)
  model = Danceba(cfg)
  before = model.style_table.detach().clone()
  opt = torch.optim.Adam(model.parameters(), lr=1e-2)   # no weight decay: untouched rows stay bit-exact
  rng = np.random.default_rng(0)
  for _ in range(2):  # the style modulation starts at zero: the style rows get gradient from the 2nd step
    inputs, targets = make_batch([tok], cfg, rng, batch=2, steps=16)
    loss = loss_of(model, inputs, targets)
    opt.zero_grad()
    loss.backward()
    opt.step()
    assert torch.isfinite(loss)
  moved = (model.style_table.detach() != before).any(1)
  assert moved.tolist() == [i == td.style_index("break") for i in range(cfg.n_styles + 1)]
