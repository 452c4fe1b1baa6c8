"""Training with the state carried across a song: lanes walk whole songs window by window."""
import numpy as np
import pytest
import torch

from training.model import SeqConfig
from training.model.danceba import Danceba
from training.common.lanes import Lanes, detach, reset_rows
from training.common.seq_loss import code_loss, song_loss
from training.common.tokens import window_probs

K = 16


def _tokens(lens=(90, 200, 130, 70), f=5, p=8, seed=0):
  rng = np.random.default_rng(seed)
  return [{"id": f"c{i}", "factor": 1.0, "style": i % 2, "upper": rng.integers(0, K, n),
           "lower": rng.integers(0, K, n), "music": rng.standard_normal((n, 4 * f)).astype(np.float32),
           "pre": rng.uniform(-1, 1, (n, p)).astype(np.float32)} for i, n in enumerate(lens)]


def _cfg(**kw):
  return SeqConfig(feature_dim=5, pre_dim=8, d_model=16, n_heads=2, codebook_size=K, n_styles=2, style_dim=4,
                   attn_window=6, **kw)


@pytest.mark.parametrize("lookahead", [0, 1])
def test_each_lane_walks_its_song_window_by_window_from_the_start(lookahead):
  toks = _tokens()
  cfg = _cfg(music_lookahead_steps=lookahead)
  lanes = Lanes(toks, cfg, np.random.default_rng(0), batch=3, steps=16)
  seen = [[] for _ in range(3)]
  for _ in range(40):
    (music, pre, u, l, sw), (tu, tl), fresh = lanes.next()
    for lane in range(3):
      j, t0 = lanes.clip[lane], lanes.pos[lane] - 16
      t = toks[j]
      assert bool(fresh[lane]) == (t0 == 0)
      np.testing.assert_array_equal(tu[lane].numpy(), t["upper"][t0 + 1:t0 + 17])
      np.testing.assert_array_equal(tl[lane].numpy(), t["lower"][t0 + 1:t0 + 17])
      np.testing.assert_array_equal(music[lane].numpy(), t["music"][t0 + lookahead:t0 + lookahead + 16])
      want_u = t["upper"][t0:t0 + 16].copy()
      if t0 == 0:
        want_u[0] = K  # BOS at the song's start
      np.testing.assert_array_equal(u[lane].numpy(), want_u)  # no past-motion dropout asked
      assert sw[lane, t["style"]] == 1
      seen[lane].append((j, t0))
  for walk in seen:  # consecutive windows of one song, then the next song from its start
    for (j0, a), (j1, b) in zip(walk, walk[1:]):
      assert (j1 == j0 and b == a + 16) or b == 0
  # every window fits: a song of 70 steps gives 4 windows of 16 (the last step's target is step 69)
  assert max(t0 for walk in seen for j, t0 in walk if j == 3) <= 70 - 16 - 1 - lookahead


def test_lanes_give_each_song_window_probs_share_of_the_windows():
  toks = _tokens(lens=(90, 400, 130, 200))
  cfg = _cfg()
  for balance in (1.0, 0.0):
    lanes = Lanes(toks, cfg, np.random.default_rng(1), batch=8, steps=16, style_balance=balance)
    counts = np.zeros(4)
    for _ in range(1500):
      lanes.next()
      for j in lanes.clip:
        counts[j] += 1
    # window_probs counts window starts; a lane takes whole windows only, so compare per style
    want = window_probs(toks, np.arange(4), 16, balance)
    got = counts / counts.sum()
    for st in (0, 1):
      assert got[st::2].sum() == pytest.approx(want[st::2].sum(), abs=0.04)


def test_lanes_snapshot_restores_the_walk():
  toks = _tokens()
  a = Lanes(toks, _cfg(), np.random.default_rng(2), batch=2, steps=16)
  for _ in range(7):
    a.next(code_mask=0.3)
  snap, state = a.snapshot(), a.rng.bit_generator.state
  want = [a.next(code_mask=0.3) for _ in range(5)]
  b = Lanes(toks, _cfg(), np.random.default_rng(99), batch=2, steps=16)
  b.restore(snap)
  b.rng.bit_generator.state = state
  for (wi, wt, wf), (gi, gt, gf) in zip(want, [b.next(code_mask=0.3) for _ in range(5)]):
    for x, y in zip(wi + wt, gi + gt):
      assert torch.equal(x, y)
    assert torch.equal(wf, gf)


def test_reset_rows_starts_the_fresh_rows_from_nothing():
  torch.manual_seed(0)
  cfg = _cfg()
  model = Danceba(cfg).eval()
  toks = _tokens()
  lanes = Lanes(toks, cfg, np.random.default_rng(3), batch=2, steps=16)
  inputs, _, _ = lanes.next()
  _, _, state = model.forward_with_state(*inputs, None)
  fresh = torch.tensor([False, True])
  reset = reset_rows(detach(state), fresh)
  # a reset row computes what a window from no state computes; the other keeps its past
  x = [t[1:] for t in inputs]
  want, _, _ = model.forward_with_state(*x, None)
  got, _, _ = model.forward_with_state(*inputs, reset)
  torch.testing.assert_close(got[1:], want, atol=1e-5, rtol=1e-5)
  kept, _, _ = model.forward_with_state(*inputs, state)
  torch.testing.assert_close(got[:1], kept[:1])
  assert not torch.allclose(got[:1], want)


def test_training_with_carried_state_and_the_song_loss():
  torch.manual_seed(0)
  cfg = _cfg()
  model = Danceba(cfg)
  toks = _tokens()
  lanes = Lanes(toks, cfg, np.random.default_rng(4), batch=3, steps=16)
  opt = torch.optim.AdamW(model.parameters(), lr=1e-2)
  carried, losses = None, []
  for _ in range(6):
    inputs, targets, fresh = lanes.next(code_mask=0.4, style_dropout=0.2)
    carried = reset_rows(detach(carried), fresh)
    lu, ll, after = model.forward_with_state(*inputs, carried)
    carried = detach(after)
    loss = code_loss(lu, ll, targets)
    opt.zero_grad()
    loss.backward()
    opt.step()
    losses.append(float(loss))
  assert all(np.isfinite(losses))
  # the song loss runs each song once from its start: the same as the whole song in one window
  model.eval()
  one = song_loss(model, toks[:1], cfg, window=1000)
  assert song_loss(model, toks[:1], cfg, window=7) == pytest.approx(one, rel=1e-5)
  t = toks[0]
  u = torch.as_tensor(t["upper"][:89]).long().clone()[None]
  l = torch.as_tensor(t["lower"][:89]).long().clone()[None]
  u[0, 0] = l[0, 0] = K
  with torch.no_grad():
    lu, ll = model(torch.as_tensor(t["music"][:89])[None], torch.as_tensor(t["pre"][:89])[None], u, l,
                   torch.tensor([[1.0, 0.0, 0.0]]))
    want = float(code_loss(lu, ll, (torch.as_tensor(t["upper"][1:90]).long()[None],
                                   torch.as_tensor(t["lower"][1:90]).long()[None])))
  assert one == pytest.approx(want, rel=1e-5)


def test_lanes_need_a_song_longer_than_a_window():
  with pytest.raises(ValueError, match="longer than one window"):
    Lanes(_tokens(lens=(10, 12)), _cfg(), np.random.default_rng(0), batch=2, steps=16)
