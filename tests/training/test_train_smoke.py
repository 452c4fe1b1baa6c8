"""Two-step training smoke tests on tiny synthetic data: losses are finite, parameters move, resume works."""
import numpy as np
import torch

from training.model import SeqConfig, VQConfig
from training.model.danceba import Danceba
from training.common.seq_inputs import own_code_inputs
from training.common.seq_loss import loss_of, validation
from training.common.tokens import make_batch, window_probs
from training.common.vq_training import integrate_root_torch, train_vq


def _tokens(n_clips=3, n=90, k=16, f=5, p=8, seed=0):
  rng = np.random.default_rng(seed)
  return [{"id": f"c{i}", "factor": 1.0, "style": i % 2, "upper": rng.integers(0, k, n),
           "lower": rng.integers(0, k, n), "music": rng.standard_normal((n, 4 * f)).astype(np.float32),
           "pre": rng.uniform(-1, 1, (n, p)).astype(np.float32)} for i in range(n_clips)]


def test_seq_two_steps():
  torch.manual_seed(0)
  cfg = SeqConfig(feature_dim=5, pre_dim=8, d_model=16, n_heads=2, codebook_size=16, n_styles=2, style_dim=4,
                  attn_window=8)
  model = Danceba(cfg)
  toks = _tokens()
  rng = np.random.default_rng(0)
  opt = torch.optim.AdamW(model.parameters(), lr=1e-2)
  before = model.head_upper.weight.clone()
  losses = []
  for _ in range(2):
    inputs, targets = make_batch(toks, cfg, rng, batch=4, steps=16, code_mask=0.4, style_dropout=0.2)
    assert inputs[2].max() <= cfg.codebook_size and targets[0].max() < cfg.codebook_size
    loss = loss_of(model, inputs, targets)
    opt.zero_grad()
    loss.backward()
    opt.step()
    losses.append(float(loss))
  assert all(np.isfinite(losses)) and abs(losses[0] - np.log(16)) < 1.0
  assert not torch.equal(before, model.head_upper.weight)
  v = validation(model, toks, cfg, n_batches=1)
  assert np.isfinite(v["music_gap"])


def test_own_code_inputs_replace_real_codes_by_the_models_draws():
  torch.manual_seed(0)
  cfg = SeqConfig(feature_dim=5, pre_dim=8, d_model=16, n_heads=2, codebook_size=16, n_styles=2, style_dim=4,
                  attn_window=8)
  model = Danceba(cfg)

  class Fixed(torch.nn.Module):  # a head that predicts one code at every step, whatever the model read
    def __init__(self, code):
      super().__init__()
      self.code = code

    def forward(self, y):
      return torch.nn.functional.one_hot(torch.full(y.shape[:-1], self.code), 16).float() * 50.0

  model.head_upper, model.head_lower = Fixed(7), Fixed(3)
  music, pre = torch.randn(2, 12, 4 * 5), torch.randn(2, 12, 8)
  u = torch.tensor([[16, 1, 16, 2, 3, 4, 5, 6, 8, 9, 10, 11], [0, 1, 2, 16, 4, 5, 6, 8, 9, 10, 11, 12]])
  l = u.flip(1).clone()
  sw = torch.zeros(2, 3)
  sw[:, 0] = 1
  inputs = (music, pre, u, l, sw)
  lu, ll = model(*inputs)
  assert (lu.argmax(-1) == 7).all() and (ll.argmax(-1) == 3).all()
  _, _, mu, ml, _ = own_code_inputs(model, inputs, 1.0)
  for real, mixed, own in ((u, mu, 7), (l, ml, 3)):
    assert torch.equal(mixed[:, 0], real[:, 0])  # step 0 (BOS at the song start, or the real code) stays
    bos = real == 16
    assert torch.equal(mixed[bos], real[bos])  # past-motion dropout stays
    assert (mixed[:, 1:][~bos[:, 1:]] == own).all()
  _, _, mu, ml, _ = own_code_inputs(model, inputs, 0.0)
  assert torch.equal(mu, u) and torch.equal(ml, l)
  gen = torch.Generator().manual_seed(1)
  big = (music.repeat(50, 1, 1), pre.repeat(50, 1, 1), u.repeat(50, 1), l.repeat(50, 1), sw.repeat(50, 1))
  _, _, mu, _, _ = own_code_inputs(model, big, 0.3, gen)
  changed = (mu[:, 1:] != big[2][:, 1:]).float().sum() / (big[2][:, 1:] != 16).float().sum()
  assert 0.25 < float(changed) < 0.35


def test_own_code_input_passes_compound_the_models_own_drift():
  k = 16

  class Successor:  # predicts at step t the code it read at step t, plus one: the next code is "input + 1"
    cfg = SeqConfig(codebook_size=k)

    def forward_with_state(self, music, pre, u, l, sw, state):
      return (torch.nn.functional.one_hot((u + 1) % k, k).float() * 100.0,
              torch.nn.functional.one_hot((l + 1) % k, k).float() * 100.0, state)

  u = torch.tensor([[k, 5, 9, 0, 3, 3, 7]])
  inputs = (torch.zeros(1, 7, 4), torch.zeros(1, 7, 2), u, u.clone(), torch.zeros(1, 3))
  for passes in (1, 2, 3):
    _, _, mu, ml, _ = own_code_inputs(Successor(), inputs, 1.0, passes=passes)
    # After n passes input t is the model's n-step continuation of the real code n steps back (t >= n).
    expected = u.clone()
    for t in range(1, 7):
      src = max(t - passes, 0)
      expected[0, t] = (u[0, src] + (t - src)) % k  # BOS (k) continues like code 0: 1, 2, ...
    assert torch.equal(mu, expected), (passes, mu, expected)
    assert torch.equal(ml, mu)


def test_batch_targets_are_next_period_codes():
  cfg = SeqConfig(feature_dim=5, pre_dim=8, codebook_size=16, n_styles=2)
  toks = _tokens(n_clips=1, n=40)
  for t in toks:  # codes = period index, so the target is the input + 1
    t["upper"] = np.arange(40) % 16
    t["lower"] = np.arange(40) % 16
  inputs, targets = make_batch(toks, cfg, np.random.default_rng(1), batch=8, steps=10)
  u, tu = inputs[2], targets[0]
  ok = u < 16
  assert torch.equal(tu[ok], (u[ok] + 1) % 16)


def test_style_balance_sets_each_styles_share_of_the_windows():
  # Style 0: three clips of 110 window starts; style 1: one clip of 30 (the data's shares 11 : 1).
  toks = [{"style": 0, "upper": np.zeros(126)} for _ in range(3)] + [{"style": 1, "upper": np.zeros(46)}]
  ok = np.arange(4)
  data = window_probs(toks, ok, steps=16)
  assert np.allclose(data, [110 / 360] * 3 + [30 / 360])
  equal = window_probs(toks, ok, steps=16, style_balance=0.0)
  assert np.allclose(equal, [1 / 6] * 3 + [0.5])
  half = window_probs(toks, ok, steps=16, style_balance=0.5)
  assert np.isclose(half[3] / half[:3].sum(), np.sqrt(30 / 330))
  assert np.allclose(half[:3], half[0])  # within a style the clips keep their relative weights
  # make_batch draws the balanced shares (style 1 is the last clip, its own style in the weights).
  cfg = SeqConfig(feature_dim=5, pre_dim=8, codebook_size=16, n_styles=2)
  clips = _tokens(n_clips=4, n=126)
  for c, st in zip(clips, (0, 0, 0, 1)):
    c["style"] = st
  clips[3] = {k: (v[:46] if isinstance(v, np.ndarray) else v) for k, v in clips[3].items()}
  drawn = [make_batch(clips, cfg, np.random.default_rng(i), batch=64, steps=16, style_balance=b)[0][4][:, 1]
           for i, b in ((0, 1.0), (1, 0.0))]
  assert abs(float(drawn[0].mean()) - 30 / 360) < 0.06 and abs(float(drawn[1].mean()) - 0.5) < 0.15


def test_a_songs_tempo_versions_share_its_weight():
  # Song a (style 0) at three tempo factors, song b (style 0) once, song c (style 1) once: a's versions
  # together weigh what a weighs alone, so augmenting one song does not raise its share.
  toks = ([{"id": "a", "style": 0, "upper": np.zeros(116)} for _ in range(3)]
          + [{"id": "b", "style": 0, "upper": np.zeros(66)}, {"id": "c", "style": 1, "upper": np.zeros(36)}])
  probs = window_probs(toks, np.arange(5), steps=16)
  assert np.allclose(probs, [100 / 170 / 3] * 3 + [50 / 170, 20 / 170])
  alone = window_probs(toks[2:], np.arange(3), steps=16, style_balance=0.5)
  assert np.allclose(window_probs(toks, np.arange(5), steps=16, style_balance=0.5)[2:], [alone[0] / 3, *alone[1:]])


def test_vq_two_steps_and_resume(tmp_path):
  rng = np.random.default_rng(0)
  arrays = [rng.standard_normal((80, 31)).astype(np.float32) * 0.01 for _ in range(2)]
  cfg = VQConfig(in_dim=31, width=8, code_dim=4, codebook_size=8)
  logs = []
  vq, hist = train_vq("lower", arrays, cfg, iters=2, ckpt_path=tmp_path / "vq.pt", log=logs.append, batch=4)
  assert (tmp_path / "vq.pt").is_file() and np.isfinite(hist[-1]["loss"])
  vq2, hist2 = train_vq("lower", arrays, cfg, iters=3, ckpt_path=tmp_path / "vq.pt", log=logs.append, batch=4)
  assert hist2[-1]["iter"] == 2  # resumed at iteration 2, ran one more


def test_vq_resume_continues_the_uninterrupted_run(tmp_path):
  rng = np.random.default_rng(1)
  arrays = [rng.standard_normal((80, 31)).astype(np.float32) * 0.01 for _ in range(3)]
  cfg = VQConfig(in_dim=31, width=8, code_dim=4, codebook_size=8)
  straight, _ = train_vq("upper", arrays, cfg, iters=6, ckpt_path=tmp_path / "a.pt", log=lambda m: None,
                         batch=4)
  train_vq("upper", arrays, cfg, iters=6, ckpt_path=tmp_path / "b.pt", log=lambda m: None, batch=4,
           stop_after=3)
  assert torch.load(tmp_path / "b.pt")["iter"] == 3
  resumed, _ = train_vq("upper", arrays, cfg, iters=6, ckpt_path=tmp_path / "b.pt", log=lambda m: None,
                        batch=4)
  a, b = straight.state_dict(), resumed.state_dict()
  moved = [k for k in a if not torch.equal(a[k], b[k])]
  assert not moved, moved


def test_root_integration_matches_representation():
  from training.data import representation as rep
  rng = np.random.default_rng(0)
  lower = rng.standard_normal((50, 31)) * 0.02
  theta, root = rep.integrate_root(lower)
  th_t, path_t = integrate_root_torch(torch.from_numpy(lower)[None])
  np.testing.assert_allclose(th_t[0].numpy(), theta, atol=1e-9)
  np.testing.assert_allclose(path_t[0].numpy(), root[:, [0, 2]], atol=1e-9)


def test_vq_path_weight_scales_only_the_root_path_term():
  from training.model.vqvae import PoseVQVAE
  from training.common.vq_training import vq_loss
  torch.manual_seed(0)
  x = torch.randn(2, 16, 31) * 0.02
  losses = {}
  for w in (0.0, 1.0, 3.0):
    torch.manual_seed(1)  # same weights and same codebook initialisation for every weight
    vq = PoseVQVAE(VQConfig(in_dim=31, width=8, code_dim=4, codebook_size=8, path_weight=w))
    vq.eval()
    losses[w] = vq_loss(vq, x, "lower")
  path = losses[1.0][1]["path"]
  assert path > 0
  assert abs(float(losses[1.0][0]) - float(losses[0.0][0]) - path) < 1e-5
  assert abs(float(losses[3.0][0]) - float(losses[0.0][0]) - 3 * path) < 1e-5


def test_vq_vel_and_acc_weights_scale_their_terms():
  from training.model.vqvae import PoseVQVAE
  from training.common.vq_training import vq_loss
  x = torch.randn(2, 16, 45) * 0.05
  out = {}
  for vw, aw in ((1.0, 1.0), (3.0, 1.0), (1.0, 4.0)):
    torch.manual_seed(1)
    vq = PoseVQVAE(VQConfig(in_dim=45, width=8, code_dim=4, codebook_size=8, vel_weight=vw, acc_weight=aw))
    vq.eval()
    out[(vw, aw)] = vq_loss(vq, x, "upper")
  base, logs = out[(1.0, 1.0)]
  assert logs["vel"] > 0 and logs["acc"] > 0
  assert abs(float(out[(3.0, 1.0)][0]) - float(base) - 2 * logs["vel"]) < 1e-5
  assert abs(float(out[(1.0, 4.0)][0]) - float(base) - 3 * logs["acc"]) < 1e-5


def test_time_base_meta_writes_the_period_locks_reach_and_style_weights(tmp_path):
  import dataclasses
  import json

  import pytest

  from training import train
  from training.common.run_meta import time_base_meta
  from training.run_config import RunConfig
  (tmp_path / "style_reference_bpm.json").write_text(json.dumps({"waltz": 87.0, "tango": 128.0}))
  (tmp_path / "dance_period_beats.json").write_text(json.dumps({"waltz": 3, "tango": 2}))
  config = RunConfig(tempo_ref=105.0, period_lock=8.0, period_lock_periods=(1, 2), bar_clock=False,
                     style_period_lock=train.parse_style_weights("waltz=0, tango=2.5"), period_lock_sharpness=10.0)
  tb = time_base_meta(config, tmp_path, print)
  assert tb["kind"] == "tempo" and tb["dance_period_beats"] == {"waltz": 3, "tango": 2}
  assert tb["period_lock"] == 8.0 and tb["period_lock_periods"] == {"upper": 1, "lower": 2}
  assert tb["style_period_lock"] == {"waltz": 0.0, "tango": 2.5} and tb["period_lock_sharpness"] == 10.0
  config = dataclasses.replace(config, style_period_lock=train.parse_style_weights(""))
  assert "style_period_lock" not in time_base_meta(config, tmp_path, print)
  # The tempo fold: written only when asked for, and its tokens are cached apart from the unfolded ones.
  from training.common.run_meta import warp_tag
  assert "fold_tempo" not in time_base_meta(config, tmp_path, print)
  config = dataclasses.replace(config, fold_tempo=True)
  assert time_base_meta(config, tmp_path, print)["fold_tempo"] is True
  refs = {"waltz": 87.0, "tango": 128.0}
  assert warp_tag(refs, None, True) == warp_tag(refs) + "_fold"
  config = dataclasses.replace(config, tempo_ref=0.0)
  assert time_base_meta(config, tmp_path, print) == {"kind": "fixed"}
  with pytest.raises(SystemExit) as e:
    train.main(["--run", str(tmp_path / "never"), "--fold-tempo", "--tempo-ref", "0"])
  assert e.value.code == 2
  # The one command refuses a reach outside 1..4 or not two integers before doing anything.
  for bad in ("0,2", "1,5", "2", "1,2,1", "a,b"):
    with pytest.raises(SystemExit) as e:
      train.main(["--run", str(tmp_path / "never"), "--period-lock-periods", bad])
    assert e.value.code == 2
  # ... and per-style weights outside 0..100, of unknown styles or not STYLE=B.
  for bad in ("waltz=101", "waltz=-1", "foxtrot=2", "waltz", "waltz=x"):
    with pytest.raises(SystemExit) as e:
      train.main(["--run", str(tmp_path / "never"), "--style-period-lock", bad])
    assert e.value.code == 2
  for bad in ("0.5", "101"):
    with pytest.raises(SystemExit) as e:
      train.main(["--run", str(tmp_path / "never"), "--period-lock-sharpness", bad])
    assert e.value.code == 2
  # The vqdec stage's energy weight: one number for both parts, or per part (a part not named: 0).
  assert train.parse_part_weights("0.3") == {"upper": 0.3, "lower": 0.3}
  assert train.parse_part_weights("upper=0.1, lower=0.3") == {"upper": 0.1, "lower": 0.3}
  assert train.parse_part_weights("lower=1") == {"upper": 0.0, "lower": 1.0}
  for bad in ("-1", "upper=-0.1", "arms=0.1", "upper", "upper=x"):
    with pytest.raises(SystemExit) as e:
      train.main(["--run", str(tmp_path / "never"), "--vq-energy-weight", bad])
    assert e.value.code == 2
  # The owndec stage's seeds and weights.
  for flag, bad in (("--own-seeds", "1,x"), ("--own-seeds", ""), ("--own-weight", "-1"), ("--own-weight", "lower=x"), ("--own-anchor", "-0.5"),
                    ("--own-iters", "-3"), ("--style-balance", "-0.1"), ("--style-balance", "1.5"),
                    ("--own-inputs", "-0.1"), ("--own-inputs", "1.5"), ("--own-passes", "0"),
                    ("--music-dropout", "-0.1"), ("--music-dropout", "1.5"),
                    ("--music-dropout", "1"),  # never reads the music: refused unless --music-guidance 0
                    ("--music-dropout-features", "0:109"), ("--music-dropout-features", "5:5"),
                    ("--music-dropout-features", "0-52"), ("--music-dropout-features", "x:2"),
                    ("--music-dropout-features", "0:52"),  # without --music-dropout it would do nothing
                    ("--music-guidance", "-0.5"), ("--music-guidance", "101"),
                    ("--own-passes", "3"),  # without --own-inputs it would do nothing
                    ("--self-share", "0"), ("--self-share", "1"), ("--self-tokens", str(tmp_path / "none.pt"))):
    with pytest.raises(SystemExit) as e:
      train.main(["--run", str(tmp_path / "never"), flag, bad])
    assert e.value.code == 2
  (tmp_path / "own.pt").write_bytes(b"")
  with pytest.raises(SystemExit) as e:  # whole-song lanes do not mix in the own draws
    train.main(["--run", str(tmp_path / "never"), "--self-tokens", str(tmp_path / "own.pt"), "--carry-state"])
  assert e.value.code == 2
  assert not (tmp_path / "never").exists()


def test_aux_heads_predict_the_codes_two_and_more_steps_ahead():
  from training.common.seq_loss import AuxHeads
  k = 16
  cfg = SeqConfig(feature_dim=5, pre_dim=8, d_model=4, n_heads=2, codebook_size=k, n_styles=2, style_dim=4,
                  attn_window=8)
  toks = _tokens(n_clips=2, n=90, k=k)
  for t in toks:  # code of step i = i mod k: the code j steps ahead of an input code c is (c + j) mod k
    t["upper"] = np.arange(90) % k
    t["lower"] = np.arange(90) % k
  inputs, targets = make_batch(toks, cfg, np.random.default_rng(0), batch=8, steps=16)

  class Ahead(torch.nn.Module):  # reads the input code from the hidden state, predicts it + j
    def __init__(self, j):
      super().__init__()
      self.j = j

    def forward(self, h):
      return torch.nn.functional.one_hot((h[..., 0].long() + self.j) % k, k).float() * 50.0

  aux = AuxHeads(4, k, steps=4)
  aux.upper = torch.nn.ModuleList(Ahead(j) for j in (2, 3, 4))
  aux.lower = torch.nn.ModuleList(Ahead(j) for j in (2, 3, 4))
  y = torch.zeros(8, 16, 3, 4)
  y[:, :, 1, 0], y[:, :, 2, 0] = inputs[2].float(), inputs[3].float()   # BOS (k) reads as code 0
  assert float(aux.loss(y, targets)) < 1e-6
  aux.upper[1] = Ahead(2)  # the 3-steps-ahead head off by one: the loss sees it
  assert float(aux.loss(y, targets)) > 1.0


def test_music_dropout_replaces_whole_windows_music_by_the_mean_and_keeps_the_rest():
  from training.common.seq_inputs import drop_music
  cfg = SeqConfig(feature_dim=5, pre_dim=8, d_model=16, n_heads=2, codebook_size=16, n_styles=2, style_dim=4,
                  attn_window=8)
  model = Danceba(cfg)
  with torch.no_grad():
    model.music_mean.copy_(torch.arange(cfg.music_dim, dtype=torch.float32))
  inputs, _ = make_batch(_tokens(), cfg, np.random.default_rng(0), batch=400, steps=16)
  out = drop_music(model, inputs, 0.3, np.random.default_rng(1))
  music, dropped = inputs[0], out[0]
  is_mean = (dropped == model.music_mean).all(-1).all(-1)
  untouched = (dropped == music).all(-1).all(-1)
  assert bool((is_mean | untouched).all()) and abs(float(is_mean.float().mean()) - 0.3) < 0.06
  for a, b in zip(inputs[1:], out[1:]):  # PRE, codes and style as they were
    assert torch.equal(a, b)
  assert not torch.equal(music, dropped)
  assert not bool((music == model.music_mean).all(-1).all(-1).any())  # the caller's batch is not changed


def test_music_dropout_of_some_feature_columns_keeps_the_others_and_is_written_for_the_engine():
  from training.common.run_meta import sampling_meta
  from training.common.seq_inputs import drop_music
  from training.run_config import RunConfig
  cfg = SeqConfig(feature_dim=5, pre_dim=8, d_model=16, n_heads=2, codebook_size=16, n_styles=2, style_dim=4,
                  attn_window=8)
  model = Danceba(cfg)
  with torch.no_grad():
    model.music_mean.copy_(-1.0 - torch.arange(cfg.music_dim, dtype=torch.float32))  # no music value is a mean
  inputs, _ = make_batch(_tokens(), cfg, np.random.default_rng(0), batch=400, steps=16)
  ranges = [(0, 2), (3, 4)]
  out = drop_music(model, inputs, 0.3, np.random.default_rng(1), ranges)
  music, dropped = inputs[0], out[0]
  cols = torch.tensor([c % cfg.feature_dim in (0, 1, 3) for c in range(cfg.music_dim)])  # every frame's 0, 1, 3
  is_mean = (dropped[..., cols] == model.music_mean[cols]).all(-1).all(-1)
  assert abs(float(is_mean.float().mean()) - 0.3) < 0.06
  assert torch.equal(dropped[..., ~cols], music[..., ~cols])  # the other columns stay the song's
  assert torch.equal(dropped[~is_mean], music[~is_mean])      # windows not drawn are untouched
  # The same draws as dropping every column: the ranges change what is replaced, not which windows.
  whole = drop_music(model, inputs, 0.3, np.random.default_rng(1))[0]
  assert torch.equal((whole == model.music_mean).all(-1).all(-1), is_mean)
  # The exported metadata tells the engine which columns its music-mean lanes replace.
  config = RunConfig(guidance=3.0, music_guidance=0.5, music_dropout=0.3, music_dropout_features=tuple(ranges))
  assert sampling_meta(config) == {"guidance": 3.0, "music_guidance": 0.5, "music_guidance_features": [[0, 2], [3, 4]]}
  assert sampling_meta(RunConfig(guidance=3.0)) == {"guidance": 3.0}


def test_music_dropout_1_reads_the_mean_and_validates_on_it():
  from training.common.seq_inputs import drop_music, mean_music_tokens
  cfg = SeqConfig(feature_dim=5, pre_dim=8, d_model=16, n_heads=2, codebook_size=16, n_styles=2, style_dim=4,
                  attn_window=8)
  model = Danceba(cfg)
  with torch.no_grad():
    model.music_mean.copy_(-1.0 - torch.arange(cfg.music_dim, dtype=torch.float32))
  toks = _tokens()
  before = [np.array(t["music"]) for t in toks]
  for ranges in (None, [(1, 3)]):
    # Dropping with probability 1 is what the validation tokens hold: the same windows, the same music.
    masked = mean_music_tokens(model, toks, ranges)
    a, _ = make_batch(toks, cfg, np.random.default_rng(0), batch=32, steps=16)
    b, _ = make_batch(masked, cfg, np.random.default_rng(0), batch=32, steps=16)
    dropped = drop_music(model, a, 1.0, np.random.default_rng(1), ranges)
    assert torch.equal(dropped[0], b[0])
    for x, y in zip(a[1:], b[1:]):
      assert torch.equal(x, y)
    assert not torch.equal(a[0], b[0])
  assert all(np.array_equal(t["music"], m) for t, m in zip(toks, before))  # the caller's tokens unchanged
  # The validation reads what the engine runs: the mean at music guidance 0 (in the dropped columns), the
  # song's music at any other weight.
  import dataclasses

  from training.common.seq_inputs import as_the_engine_reads
  from training.run_config import RunConfig
  config = RunConfig(guidance=3.0, music_guidance=0.0, music_dropout=1.0, music_dropout_features=((1, 3),))
  for got, want in zip(as_the_engine_reads(config, model, toks), mean_music_tokens(model, toks, [(1, 3)])):
    assert np.array_equal(got["music"], want["music"])
  config = dataclasses.replace(config, music_guidance=0.5)
  assert as_the_engine_reads(config, model, toks) is toks

