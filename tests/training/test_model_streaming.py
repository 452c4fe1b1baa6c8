"""The streaming step form of every model part equals the parallel (training) form."""
import numpy as np
import pytest
import torch

from training.model import DecoderStream, PoseVQVAE, SeqConfig, VQConfig
from training.model.danceba import Danceba, one_hot_style
from training.model.layers import set_residual_dropout
from training.model.mamba import Mamba
from training.model.tgca import TGCABlock


def _perturb(module, scale=0.2, seed=0):
  g = torch.Generator().manual_seed(seed)
  with torch.no_grad():
    for p in module.parameters():
      p.add_(torch.randn(p.shape, generator=g) * scale)


def test_mamba_step_equals_sequence():
  torch.manual_seed(0)
  m = Mamba(16, d_state=4, d_conv=4, expand=2)
  _perturb(m)
  h = torch.randn(3, 20, 16)
  full = m(h)
  state, outs = None, []
  for t in range(20):
    o, state = m.step(h[:, t], state)
    outs.append(o)
  torch.testing.assert_close(torch.stack(outs, 1), full, atol=1e-5, rtol=1e-5)


def test_tgca_window_beyond_training_length():
  torch.manual_seed(1)
  blk = TGCABlock(16, 2, window=4, d_s=4, r=0.25)
  _perturb(blk)
  x, sv = torch.randn(2, 11, 3, 16), torch.randn(2, 4)
  full = blk(x, sv)
  state, outs = None, []
  for t in range(11):
    o, state = blk.step(x[:, t], sv, state)
    outs.append(o)
    assert state["k"].shape[2] <= 3 * 3  # cache keeps W-1 past steps
  torch.testing.assert_close(torch.stack(outs, 1), full, atol=1e-5, rtol=1e-5)


def test_tgca_is_causal():
  torch.manual_seed(2)
  blk = TGCABlock(16, 2, window=8, d_s=4, r=0.25)
  x, sv = torch.randn(1, 6, 3, 16), torch.randn(1, 4)
  y1 = blk(x, sv)
  x2 = x.clone()
  x2[:, 4:] += 1.0
  y2 = blk(x2, sv)
  torch.testing.assert_close(y1[:, :4], y2[:, :4])
  assert not torch.allclose(y1[:, 4:], y2[:, 4:])


def _danceba_and_inputs(variant: dict, seed: int, t: int):
  """A small perturbed model (attention window 5) and random inputs of 2 rows x t steps."""
  torch.manual_seed(seed)
  cfg = SeqConfig(feature_dim=6, pre_dim=8, d_model=32, n_heads=2, codebook_size=16, attn_window=5,
                  n_styles=3, style_dim=4, **variant)
  model = Danceba(cfg)
  _perturb(model, 0.1)
  model.eval()
  mu, pre = torch.randn(2, t, 24), torch.randn(2, t, 8)
  u, l = torch.randint(0, 17, (2, t)), torch.randint(0, 17, (2, t))
  sw = torch.tensor([[0.5, 0.5, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
  return model, (mu, pre, u, l, sw)


@pytest.mark.parametrize("variant", [{}, {"shared_mamba": True}, {"use_gate": False, "use_pre": False},
                                     {"music_lookahead_steps": 1}])
def test_danceba_step_equals_parallel(variant):
  t = 13
  model, (mu, pre, u, l, sw) = _danceba_and_inputs(variant, 3, t)
  lu, ll = model(mu, pre, u, l, sw)
  state, su, sl = None, [], []
  for i in range(t):
    a, c, state = model.step(mu[:, i], pre[:, i], u[:, i], l[:, i], sw, state)
    su.append(a)
    sl.append(c)
  torch.testing.assert_close(torch.stack(su, 1), lu, atol=1e-4, rtol=1e-4)
  torch.testing.assert_close(torch.stack(sl, 1), ll, atol=1e-4, rtol=1e-4)


def test_residual_dropout_is_training_only():
  """--dropout: every residual branch of the TGCA and PMMM blocks drops in training mode; eval mode (export,
  the step form, the engine) is exactly the model without dropout, and the weights are the same tensors."""
  torch.manual_seed(4)
  cfg = SeqConfig(feature_dim=6, pre_dim=8, d_model=32, n_heads=2, codebook_size=16, attn_window=5,
                  n_styles=3, style_dim=4)
  model = Danceba(cfg)
  _perturb(model, 0.1)
  b, t = 2, 9
  args = (torch.randn(b, t, 24), torch.randn(b, t, 8), torch.randint(0, 17, (b, t)), torch.randint(0, 17, (b, t)),
          torch.tensor([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]))
  model.eval()
  plain = model(*args)[0]
  keys = set(model.state_dict())
  # 3 TGCA blocks (2 base + final) and 2 x 3 PMMM blocks, one dropout module each
  assert set_residual_dropout(model, 0.5) == cfg.n_base + 1 + 3 * cfg.n_head
  assert set(model.state_dict()) == keys
  torch.testing.assert_close(model(*args)[0], plain)
  model.train()
  torch.manual_seed(5)
  a = model(*args)[0]
  torch.manual_seed(6)
  c = model(*args)[0]
  assert not torch.allclose(a, c) and not torch.allclose(a, plain)
  set_residual_dropout(model, 0.0)  # training mode without dropout is deterministic again
  torch.manual_seed(5)
  a = model(*args)[0]
  torch.manual_seed(6)
  torch.testing.assert_close(model(*args)[0], a)


def test_decoder_is_causal_and_streams():
  torch.manual_seed(4)
  vq = PoseVQVAE(VQConfig(in_dim=31, width=16, code_dim=8, codebook_size=10)).eval()
  codes = torch.randint(0, 10, (2, 9))
  full = vq.decode_codes(codes)
  assert full.shape == (2, 36, 31)
  stream = DecoderStream(vq.decoder, 2)
  frames = torch.cat([stream.push(vq.quantizer.codebook[codes[:, i]]) for i in range(9)], 1)
  torch.testing.assert_close(frames, full, atol=1e-5, rtol=1e-5)
  changed = codes.clone()
  changed[:, 5:] = (changed[:, 5:] + 1) % 10
  torch.testing.assert_close(vq.decode_codes(changed)[:, :20], full[:, :20])  # frames of periods < 5


def test_style_none_row_and_mixing():
  w = one_hot_style(2, -1, 4)
  assert w.shape == (2, 5) and float(w[0, 4]) == 1.0
  assert np.isclose(float(one_hot_style(1, 2, 4).sum()), 1.0)


@pytest.mark.parametrize("variant", [{}, {"shared_mamba": True}])
def test_danceba_windows_with_carried_state_equal_one_window(variant):
  model, (mu, pre, u, l, sw) = _danceba_and_inputs(variant, 4, 17)
  cfg = model.cfg
  lu, ll = model(mu, pre, u, l, sw)
  # windows of 2, 6 and 9 steps (shorter and longer than the attention window), the state carried
  state, parts_u, parts_l = None, [], []
  for a, e in ((0, 2), (2, 8), (8, 17)):
    pu, pl, state = model.forward_with_state(mu[:, a:e], pre[:, a:e], u[:, a:e], l[:, a:e], sw, state)
    parts_u.append(pu)
    parts_l.append(pl)
    assert state["base0"]["k"].shape[2] == 3 * min(e, cfg.attn_window - 1)
  torch.testing.assert_close(torch.cat(parts_u, 1), lu, atol=1e-4, rtol=1e-4)
  torch.testing.assert_close(torch.cat(parts_l, 1), ll, atol=1e-4, rtol=1e-4)
  # the carried state is the streaming form's: stepping on from it equals the parallel form
  _, _, s16 = model.forward_with_state(mu[:, :16], pre[:, :16], u[:, :16], l[:, :16], sw, None)
  su, sl, _ = model.step(mu[:, 16], pre[:, 16], u[:, 16], l[:, 16], sw,
                         {k: {n: x for n, x in v.items() if n != "valid"} for k, v in s16.items()})
  torch.testing.assert_close(su, lu[:, 16], atol=1e-4, rtol=1e-4)
  torch.testing.assert_close(sl, ll[:, 16], atol=1e-4, rtol=1e-4)


def test_tgca_rows_without_a_cache_ignore_the_cached_steps():
  torch.manual_seed(5)
  blk = TGCABlock(16, 2, window=4, d_s=4, r=0.25)
  _perturb(blk)
  x, sv = torch.randn(2, 9, 3, 16), torch.randn(2, 4)
  _, state = blk.forward_with_state(x[:, :5], sv, None)
  state["valid"][1] = False  # row 1 starts a new song here: its cache is someone else's past
  y, _ = blk.forward_with_state(x[:, 5:], sv, state)
  torch.testing.assert_close(y[0], blk(x[:1], sv[:1])[0, 5:], atol=1e-5, rtol=1e-5)
  torch.testing.assert_close(y[1], blk(x[1:, 5:], sv[1:])[0], atol=1e-5, rtol=1e-5)
