import numpy as np

from training.data import skeleton as sk
from training.eval.evaluate import Dance, Evaluator
from training.model import SeqConfig
from training.experiments.self_rollouts import SEGMENT_STEPS, SegmentScorer, clip_of_run, kept_runs
from training.common.tokens import make_batch, window_probs


def test_kept_runs_are_the_consecutive_kept_segments():
  assert kept_runs(np.array([True, True, False, True, False, False, True])) == [(0, 1), (3, 3), (6, 6)]
  assert kept_runs(np.array([False, False])) == []
  assert kept_runs(np.array([True, True, True])) == [(0, 2)]


def test_clip_of_run_lines_the_draw_up_with_the_songs_music():
  n = 3 * SEGMENT_STEPS  # token steps 0..n: BOS context, then n drawn steps
  rng = np.random.default_rng(0)
  t = {"id": "tang_DANCE_W_1", "factor": 1.0, "style": 3, "upper": rng.integers(0, 16, n + 1),
       "lower": rng.integers(0, 16, n + 1), "music": np.arange(n + 1, dtype=np.float32)[:, None].repeat(4, 1),
       "pre": np.arange(n + 1, dtype=np.float32)[:, None].repeat(2, 1)}
  upper, lower = rng.integers(0, 16, n), rng.integers(0, 16, n)  # the draw: codes of token steps 1..n
  c = clip_of_run(t, upper, lower, 1, 2, draw=5)
  a = SEGMENT_STEPS
  assert c["id"] == "self:tang_DANCE_W_1:5:1" and c["style"] == 3 and c["own_draw"]
  assert len(c["upper"]) == len(c["music"]) == len(c["pre"]) == 2 * SEGMENT_STEPS + 1
  # Token step j of the clip is token step a + j of the song: its code is the draw's code of that step.
  assert c["upper"][0] == upper[a - 1] and np.array_equal(c["upper"][1:], upper[a:3 * SEGMENT_STEPS])
  assert np.array_equal(c["lower"][1:], lower[a:3 * SEGMENT_STEPS])
  assert c["music"][0, 0] == a and c["music"][-1, 0] == 3 * SEGMENT_STEPS and c["pre"][5, 1] == a + 5
  # From the song's start the context is the song's own first code (replaced by BOS in training).
  first = clip_of_run(t, upper, lower, 0, 0, draw=0)
  assert first["upper"][0] == t["upper"][0] and np.array_equal(first["upper"][1:], upper[:SEGMENT_STEPS])


def test_self_share_sets_the_own_draws_share_of_the_windows():
  toks = ([{"id": f"r{i}", "style": i % 2, "upper": np.zeros(100 + 20 * i)} for i in range(4)]
          + [{"id": f"self:r{i}:0:0", "style": i % 2, "upper": np.zeros(76), "own_draw": True} for i in range(3)])
  ok = np.arange(len(toks))
  for share in (0.2, 0.5, 0.8):
    p = window_probs(toks, ok, steps=16, style_balance=0.5, self_share=share)
    assert np.isclose(p.sum(), 1.0) and np.isclose(p[4:].sum(), share)
    # Within each part the clips keep their (style-balanced) relative weights.
    base = window_probs(toks, ok, steps=16, style_balance=0.5)
    assert np.allclose(p[:4] / p[:4].sum(), base[:4] / base[:4].sum())
    assert np.allclose(p[4:] / p[4:].sum(), base[4:] / base[4:].sum())
  # Without own draws among the clips the share changes nothing.
  assert np.allclose(window_probs(toks[:4], ok[:4], 16, 0.5, 0.3), window_probs(toks[:4], ok[:4], 16, 0.5))
  # make_batch draws them at that share (the own clips are 76 steps: windows of 64 fit).
  cfg = SeqConfig(feature_dim=5, pre_dim=8, codebook_size=16, n_styles=2)
  rng = np.random.default_rng(0)
  clips = []
  for t in toks:
    n = len(t["upper"])
    clips.append(dict(t, factor=1.0, upper=rng.integers(0, 16, n), lower=rng.integers(0, 16, n),
                      music=np.zeros((n, 20), np.float32) + (1.0 if t.get("own_draw") else 0.0),
                      pre=np.zeros((n, 8), np.float32)))
  (music, *_), _ = make_batch(clips, cfg, np.random.default_rng(1), batch=200, steps=64, self_share=0.8)
  assert abs(float(music[:, 0, 0].mean()) - 0.8) < 0.08


def _swaying(amplitude: float, seconds: float = 20.0, period_s: float = 1.7) -> np.ndarray:
  """A skeleton in its rest pose swaying sideways and bobbing (T, 24, 3)."""
  rest = sk.load_skeleton().rest_positions()
  t = np.arange(int(seconds * 30)) / 30.0
  pos = np.repeat(rest[None], len(t), 0).astype(np.float64)
  pos[..., 0] += amplitude * np.sin(2 * np.pi * t / period_s)[:, None]
  pos[..., 1] += 0.3 * amplitude * np.sin(4 * np.pi * t / period_s)[:, None]
  arms = [i for i, n in enumerate(sk.JOINT_NAMES) if "wrist" in n or "hand" in n or "elbow" in n]
  pos[:, arms, 1] += amplitude * np.cos(2 * np.pi * t / period_s)[:, None]
  return pos


def test_segments_near_the_styles_real_dancing_score_lower():
  ref = [Dance("tang_DANCE_W_1", _swaying(0.2)), Dance("tang_DANCE_C_1", _swaying(0.05, period_s=0.5))]
  val = [Dance("tang_DANCE_W_2", _swaying(0.15)), Dance("tang_DANCE_C_2", _swaying(0.08, period_s=0.6))]
  scorer = SegmentScorer(Evaluator(ref, val))
  waltz, chacha = 3, 0
  same = scorer.scores([Dance("x", _swaying(0.2))], waltz)
  near = scorer.scores([Dance("x", _swaying(0.17))], waltz)
  frozen = scorer.scores([Dance("x", _swaying(0.0))], waltz)
  assert same.shape == (2,) and np.allclose(same, 0.0, atol=1e-9)  # two 10-s segments, each a real one
  assert np.all(near > 0) and np.all(frozen > near)
  # The style matters: the waltz's sway is far from the cha-cha's real dancing.
  assert np.all(scorer.scores([Dance("x", _swaying(0.2))], chacha) > near)


def test_the_song_reward_compares_each_segment_with_the_real_dance_at_the_same_time():
  ref = [Dance("tang_DANCE_W_1", _swaying(0.2)), Dance("tang_DANCE_C_1", _swaying(0.05, period_s=0.5))]
  val = [Dance("tang_DANCE_W_2", _swaying(0.15)), Dance("tang_DANCE_C_2", _swaying(0.08, period_s=0.6))]
  scorer = SegmentScorer(Evaluator(ref, val))
  real = np.concatenate([_swaying(0.2, seconds=10), _swaying(0.05, seconds=10, period_s=0.5)])
  same, swapped = real.copy(), np.concatenate([real[300:], real[:300]])
  s = scorer.scores_against([Dance("a", same), Dance("b", swapped)], Dance("real", real))
  assert s.shape == (4,) and np.allclose(s[:2], 0.0, atol=1e-9) and np.all(s[2:] > 0.1)
