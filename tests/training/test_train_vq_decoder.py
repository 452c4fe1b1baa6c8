"""Decoder-only VQ-VAE fine-tuning (training.common.decoder_tuning, the vqdec and owndec stages): two steps on
tiny random VQ-VAEs change only the decoder; the energy term is zero for a perfect decode and positive
otherwise; the run directory's decoders are loaded only where they fit."""
import numpy as np
import torch

from training.model import VQConfig
from training.model.vqvae import PoseVQVAE
from training.common.decoder_tuning import channel_groups, energy_loss, finetune_decoder


def _tiny(dim: int) -> PoseVQVAE:
  torch.manual_seed(dim)
  return PoseVQVAE(VQConfig(in_dim=dim, width=16, code_dim=8, codebook_size=16, n_res=1,
                            vel_weight=4.0, acc_weight=4.0)).eval()


def _arrays(dim: int, seed: int = 0, lengths=(80, 100, 120)) -> list[np.ndarray]:
  rng = np.random.default_rng(seed)
  return [np.cumsum(rng.standard_normal((n, dim)), axis=0).astype(np.float32) * 0.01 for n in lengths]


def test_two_steps_change_only_the_decoder():
  for part, dim in (("upper", 45), ("lower", 31)):
    vq = _tiny(dim)
    frozen = {k: v.clone() for k, v in vq.state_dict().items() if not k.startswith("decoder.")}
    dec_before = {k: v.clone() for k, v in vq.decoder.state_dict().items()}
    hist = finetune_decoder(vq, part, _arrays(dim), iters=2, energy_weight=1.0, lr=1e-2, batch=4,
                            log=lambda msg: None, log_every=1)
    assert len(hist) == 2 and all(np.isfinite(h["loss"]) and h["energy"] > 0 for h in hist)
    after = vq.state_dict()
    for k, v in frozen.items():  # encoder, codebook and its EMA statistics, normalisation: bit-identical
      assert torch.equal(v, after[k]), f"{part}: {k} changed"
    assert any(not torch.equal(v, vq.decoder.state_dict()[k]) for k, v in dec_before.items())
    assert not vq.training


def test_energy_term_zero_iff_equal():
  groups = channel_groups(31)
  assert len(groups) == 9 + 4 and groups[9] == [27]
  assert len(channel_groups(45)) == 15
  torch.manual_seed(0)
  target = torch.randn(3, 64, 31).cumsum(1) * 0.01
  assert float(energy_loss(target.clone(), target, groups)) == 0.0
  assert float(energy_loss(0.5 * target, target, groups)) > 0.0  # too gentle
  assert float(energy_loss(target + 0.01 * torch.randn_like(target), target, groups)) > 0.0  # jittery


def test_export_with_decoders_changes_only_the_decoders(tmp_path):
  from training.export import export_model, load_models, read_dncw
  from training.model import SeqConfig
  from training.model.danceba import Danceba
  from training.experiments.vq_decoder import export_with_decoders
  torch.manual_seed(0)
  seq = Danceba(SeqConfig(feature_dim=6, pre_dim=8, d_model=16, n_heads=2, codebook_size=16, n_styles=2,
                          style_dim=4)).eval()
  vqs = {"upper": _tiny(45), "lower": _tiny(31)}
  src = tmp_path / "src.dncw"
  export_model(str(src), seq, vqs, {"model_id": "src", "styles": ["a", "b"]})
  seq2, vqs2, meta = load_models(str(src))
  for part, dim in (("upper", 45), ("lower", 31)):
    finetune_decoder(vqs2[part], part, _arrays(dim), iters=2, energy_weight=0.3, lr=1e-2, batch=4,
                     log=lambda msg: None)
  out = tmp_path / "out.dncw"
  export_with_decoders(str(out), seq2, vqs2, meta, {"energy_weight": 0.3, "export": str(out)}, "new-id")
  h0, t0 = read_dncw(str(src))
  h1, t1 = read_dncw(str(out))
  assert sorted(t0) == sorted(t1)
  changed = {n for n in t0 if not np.array_equal(t0[n], t1[n])}
  assert changed and all(n.startswith("vq.") and ".dec." in n for n in changed), sorted(changed)
  assert h1["metadata"]["model_id"] == "new-id"
  assert h1["metadata"]["training"]["vqdec"] == {"energy_weight": 0.3}
  assert h1["metadata"]["styles"] == ["a", "b"]


def test_load_vqs_prefers_the_fine_tuned_decoders(tmp_path):
  from training.common.run_dir import load_vqs
  for part, dim in (("upper", 45), ("lower", 31)):
    vq = _tiny(dim)
    torch.save({"model": vq.state_dict(), "cfg": vq.cfg.to_dict()}, tmp_path / f"vq_{part}.pt")
    with torch.no_grad():
      for p in vq.decoder.parameters():
        p.add_(1.0)
    torch.save({"model": vq.state_dict(), "cfg": vq.cfg.to_dict()}, tmp_path / f"vqdec_{part}.pt")
  tuned, plain = load_vqs(tmp_path), load_vqs(tmp_path, fine_tuned=False)
  for part in ("upper", "lower"):
    dec_t, dec_p = tuned[part].decoder.state_dict(), plain[part].decoder.state_dict()
    assert all(torch.equal(dec_t[k], dec_p[k] + 1.0) for k in dec_t if dec_t[k].is_floating_point())
    enc_t, enc_p = tuned[part].encoder.state_dict(), plain[part].encoder.state_dict()
    assert all(torch.equal(enc_t[k], enc_p[k]) for k in enc_t)


def test_step_codes_undo_the_engines_frame_warp():
  from training.common.decoder_tuning import step_codes
  rng = np.random.default_rng(3)
  up = rng.integers(0, 5, 200)       # few codes: equal consecutive steps are common
  low = rng.integers(0, 5, 200)
  up[50:60], low[50:60] = 2, 3       # a held figure: ten equal steps in a row
  frames = rng.choice([4, 5], 200, p=[0.7, 0.3])  # about 4 / 0.93 real frames per step, as the warp emits
  fu, fl = np.repeat(up, frames), np.repeat(low, frames)
  su, sl = step_codes(fu.tolist(), fl.tolist())
  assert np.array_equal(su, up) and np.array_equal(sl, low)


def _own_dances(tmp_path, n_codes: int, styles=("waltz", "rumba")):
  import json
  rng = np.random.default_rng(1)
  for i, style in enumerate(styles):
    codes = np.repeat(rng.integers(0, n_codes, 60), 4).tolist()
    lower = np.repeat(rng.integers(0, n_codes, 60), 4).tolist()
    (tmp_path / f"d{i}.json").write_text(json.dumps({"style": {style: 1.0}, "upper_codes": codes,
                                                      "lower_codes": lower}))
  return tmp_path


def test_own_codes_term_moves_each_style_toward_its_real_energy(tmp_path):
  from training.common.clips import STYLES
  from training.common.decoder_tuning import OwnCodes, energy_eps, load_own_codes
  vq = _tiny(45)
  for p in vq.parameters():
    p.requires_grad_(False)
  for p in vq.decoder.parameters():
    p.requires_grad_(True)
  dances = load_own_codes(str(_own_dances(tmp_path, 16)), "upper")
  assert sorted(s for s, _ in dances) == sorted([STYLES.index("waltz"), STYLES.index("rumba")])
  assert all(len(c) == 60 for _, c in dances)
  import json
  import pytest
  empty = tmp_path / "empty"
  empty.mkdir()
  with pytest.raises(ValueError, match="no dance files"):
    load_own_codes(str(empty), "upper")
  (empty / "x.json").write_text(json.dumps({"style": {"foxtrot": 1.0}, "upper_codes": [1], "lower_codes": [1]}))
  with pytest.raises(ValueError, match="foxtrot"):
    load_own_codes(str(empty), "upper")
  calm, wild = _arrays(45, 1), [a * 5 for a in _arrays(45, 2)]  # rumba's real motion 5x the waltz's
  real = {STYLES.index("waltz"): calm, STYLES.index("rumba"): wild}
  groups = channel_groups(45)
  eps = energy_eps(calm + wild, groups, np.random.default_rng(0))
  own = OwnCodes(vq, dances, real, groups, eps, steps=16, per_style=4, seed=0, real_windows=32,
                 anchor=1.0)
  opt = torch.optim.Adam(vq.decoder.parameters(), lr=3e-3)
  first, _ = own.loss()
  for _ in range(60):
    loss, logs = own.loss()
    opt.zero_grad()
    loss.backward()
    opt.step()
  last = float(np.mean([float(own.loss()[0]) for _ in range(4)]))
  assert np.isfinite(float(first)) and float(first) > 0
  assert last < 0.5 * float(first), (float(first), last)
  assert {"own", "anchor"} <= set(logs)


def test_finetune_with_own_codes_changes_only_the_decoder(tmp_path, monkeypatch):
  from training.common import decoder_tuning as T
  from training.common.clips import STYLES
  vq = _tiny(45)
  frozen = {k: v.clone() for k, v in vq.state_dict().items() if not k.startswith("decoder.")}
  long = (150, 200)  # at least one 32-step (128-frame) window per style
  monkeypatch.setattr(T, "real_by_style", lambda part: {STYLES.index("waltz"): _arrays(45, 1, long),
                                                        STYLES.index("rumba"): _arrays(45, 2, (90,))})
  hist = T.finetune_decoder(vq, "upper", _arrays(45), iters=2, energy_weight=0.1, lr=1e-2, batch=4,
                            log=lambda msg: None, log_every=1, own_dances=str(_own_dances(tmp_path, 16)),
                            own_weight=1.0)
  assert len(hist) == 2 and all(np.isfinite(h["own"]) and h["own"] > 0 for h in hist)
  # rumba's real clips are all shorter than a window: only the waltz is matched
  assert "own_mean_3" in hist[0] and "own_mean_1" not in hist[0]
  after = vq.state_dict()
  assert all(torch.equal(v, after[k]) for k, v in frozen.items())


def test_load_vqs_takes_the_own_decoders_only_for_their_sequence_model(tmp_path):
  from training.common.run_dir import load_vqs, seq_digest
  for part, dim in (("upper", 45), ("lower", 31)):
    vq = _tiny(dim)
    torch.save({"model": vq.state_dict(), "cfg": vq.cfg.to_dict()}, tmp_path / f"vq_{part}.pt")
  (tmp_path / "seq.pt").write_bytes(b"sequence model A")
  keys = {}
  for part, dim, shift in (("upper", 45, 1.0), ("lower", 31, 2.0)):
    vq = _tiny(dim)
    with torch.no_grad():
      for p in vq.decoder.parameters():
        p.add_(shift)
    torch.save({"model": vq.state_dict(), "cfg": vq.cfg.to_dict(), "seq_sha256": seq_digest(tmp_path)},
               tmp_path / f"owndec_{part}.pt")
    keys[part] = next(k for k in vq.decoder.state_dict() if k.endswith("weight"))
  for part, shift in (("upper", 1.0), ("lower", 2.0)):
    plain = load_vqs(tmp_path)[part].decoder.state_dict()[keys[part]]
    own = load_vqs(tmp_path, own=True)[part].decoder.state_dict()[keys[part]]
    assert torch.equal(own, plain + shift)
  (tmp_path / "owndec_lower.pt").unlink()  # a part without its own decoder keeps the plain one
  assert torch.equal(load_vqs(tmp_path, own=True)["lower"].decoder.state_dict()[keys["lower"]],
                     load_vqs(tmp_path)["lower"].decoder.state_dict()[keys["lower"]])
  (tmp_path / "seq.pt").write_bytes(b"sequence model B")  # retrained: the own decoder no longer fits
  assert torch.equal(load_vqs(tmp_path, own=True)["upper"].decoder.state_dict()[keys["upper"]],
                     load_vqs(tmp_path)["upper"].decoder.state_dict()[keys["upper"]])


def test_own_decoder_is_redone_when_its_settings_change(tmp_path):
  import dataclasses
  import json

  from training.common import run_dir as rd
  from training.run_config import RunConfig
  (tmp_path / "seq.pt").write_bytes(b"sequence model A")
  (tmp_path / "style_reference_bpm.json").write_text(json.dumps({"waltz": 87.0}))
  (tmp_path / "dance_period_beats.json").write_text(json.dumps({"waltz": 3}))
  config = RunConfig(tempo_ref=105.0, period_lock=8.0, period_lock_periods=(1, 2), bar_clock=False,
                   style_period_lock={"waltz": 0.0}, period_lock_sharpness=10.0, guidance=3.0,
                   own_seeds=(10, 11), own_iters=1000, own_weight={"upper": 1.0, "lower": 0.0}, own_anchor=100.0,
                   vq_energy_weight={"upper": 0.1, "lower": 0.3}, vq_dec_lr=1e-4)
  report = {"seq_sha256": rd.seq_digest(tmp_path), "settings": rd.owndec_settings(config, tmp_path)}
  (tmp_path / "owndec_report.json").write_text(json.dumps(report))
  assert rd.owndec_current(tmp_path, config) is not None
  assert rd.owndec_current(tmp_path) is not None  # without a config: the sequence model alone
  for name, value in (("guidance", 2.0), ("music_guidance", 0.5), ("period_lock", 4.0), ("own_seeds", (10,)),
                      ("own_weight", {"upper": 0.3, "lower": 0.0}), ("own_weight", {"upper": 1.0, "lower": 0.5})):
    changed = dataclasses.replace(config, **{name: value})
    assert rd.owndec_current(tmp_path, changed) is None, name
  (tmp_path / "seq.pt").write_bytes(b"sequence model B")
  assert rd.owndec_current(tmp_path, config) is None and rd.owndec_current(tmp_path) is None
  # The dances' directory: stamped beside the dances (which load_own_codes still reads), emptied when the
  # sampling settings change, kept when only the fine-tuning's do.
  from training.common.decoder_tuning import load_own_codes
  dances = rd.own_dances_dir(config, tmp_path)
  _own_dances(dances, 16)
  assert len(load_own_codes(str(rd.own_dances_dir(config, tmp_path)), "upper")) == 2
  other = dataclasses.replace(config, own_weight={"upper": 0.3, "lower": 0.0})
  assert len(load_own_codes(str(rd.own_dances_dir(other, tmp_path)), "upper")) == 2
  rd.own_dances_dir(dataclasses.replace(config, guidance=2.0), tmp_path)
  assert not list(dances.glob("*.json"))
