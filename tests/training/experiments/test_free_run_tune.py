import numpy as np
import torch
import torch.nn.functional as F

from training.export import load_models
from training.experiments.free_run_tune import EnergyTarget, gumbel_one_hot, rollouts, step_soft
from training.model.danceba import one_hot_style

TINY = "models/test-tiny.dncw"


def test_gumbel_one_hot_draws_from_the_softmax_and_passes_its_gradient():
  logits = torch.tensor([[2.0, 0.0, -1.0, 1.0]]).repeat(20000, 1).requires_grad_(True)
  y = gumbel_one_hot(logits, torch.Generator().manual_seed(0))
  # Forward: one-hot rows, drawn with the softmax's probabilities.
  assert torch.equal(y.detach().sum(-1), torch.ones(20000)) and set(y.detach().unique().tolist()) == {0.0, 1.0}
  freq = y.detach().mean(0)
  assert torch.allclose(freq, torch.softmax(logits[0].detach(), -1), atol=0.015)
  # Backward: the softmax's Jacobian (w . y through softmax).
  w = torch.tensor([1.0, -2.0, 0.5, 3.0])
  (y[:1] @ w).sum().backward()
  p = torch.softmax(logits[0].detach(), -1)
  assert torch.allclose(logits.grad[0], p * (w - (p * w).sum()), atol=1e-6)
  assert torch.count_nonzero(logits.grad[1:]) == 0


def _clips(cfg, n_steps: int, rng) -> list[dict]:
  k = cfg.codebook_size
  return [{"id": f"c{i}", "factor": 1.0, "style": i % 2, "upper": rng.integers(0, k, n_steps),
           "lower": rng.integers(0, k, n_steps),
           "music": rng.standard_normal((n_steps, cfg.music_dim)).astype(np.float32),
           "pre": rng.standard_normal((n_steps, cfg.pre_dim)).astype(np.float32)} for i in range(4)]


def test_step_soft_with_one_hot_inputs_equals_the_models_step():
  model, _, _ = load_models(TINY)
  cfg, k = model.cfg, model.cfg.codebook_size
  rng = np.random.default_rng(0)
  state_a = state_b = None
  u, l = torch.full((3,), k), torch.full((3,), k)
  for _ in range(5):
    m = torch.from_numpy(rng.standard_normal((3, cfg.music_dim)).astype(np.float32))
    p = torch.from_numpy(rng.standard_normal((3, cfg.pre_dim)).astype(np.float32))
    sw = one_hot_style(3, 1, cfg.n_styles)
    with torch.no_grad():
      la, lla, state_a = model.step(m, p, u, l, sw, state_a)
      lb, llb, state_b = step_soft(model, m, p, F.one_hot(u, k + 1).float(), F.one_hot(l, k + 1).float(), sw, state_b)
    assert torch.allclose(la, lb, atol=1e-5) and torch.allclose(lla, llb, atol=1e-5)
    u, l = torch.from_numpy(rng.integers(0, k, 3)), torch.from_numpy(rng.integers(0, k, 3))
  assert model.embed.__func__ is type(model).embed  # the patch is undone


def test_rollout_loss_reaches_the_sequence_model_and_not_the_decoders():
  model, vqs, _ = load_models(TINY)
  for vq in vqs.values():
    for p in vq.parameters():
      p.requires_grad_(False)
  rng = np.random.default_rng(0)
  toks = _clips(model.cfg, 60, rng)
  target = EnergyTarget(vqs, toks, steps=8, rng=rng, windows=16)
  for bos_share in (0.0, 1.0):  # from a real prefix, and from BOS at the song's start
    model.zero_grad()
    loss, logs = rollouts(model, vqs, toks, target, rng, torch.Generator().manual_seed(0), per_style=3,
                          prefix=6, steps=8, bos_share=bos_share)
    assert torch.isfinite(loss) and float(loss) > 0 and set(logs) >= {"own", "z_upper_0", "z_lower_1"}
    loss.backward()
    # The draws' gradient reaches the heads (through the softmax) and the code embeddings (through the
    # draws read by later steps).
    for param in (model.head_upper.weight, model.head_lower.weight, model.embed_upper.weight):
      assert param.grad is not None and float(param.grad.abs().sum()) > 0
    assert all(p.grad is None for vq in vqs.values() for p in vq.parameters())


def test_energy_target_of_the_real_codes_scores_them_near_zero():
  model, vqs, _ = load_models(TINY)
  rng = np.random.default_rng(1)
  toks = _clips(model.cfg, 80, rng)
  target = EnergyTarget(vqs, toks, steps=8, rng=rng, windows=64)
  # Real windows of style 0, decoded the same way, score near the target; the same windows slowed down
  # (every frame twice: a quarter of the velocity energy) score far from it.
  wins = []
  for t in toks:
    if t["style"] != 0:
      continue
    with torch.no_grad():
      d = vqs["upper"].denormalise(vqs["upper"].decode_codes(torch.as_tensor(t["upper"])[None].long()))[0]
    for o in range(16, len(d) - 32, 8):
      wins.append(d[o:o + 32])
  real = torch.stack(wins)
  slow = real.repeat_interleave(2, dim=1)[:, :32]
  near, _ = target.loss("upper", 0, real)
  far, z = target.loss("upper", 0, slow)
  assert float(near) < 0.2 < float(far) and z < -0.5


def test_per_song_target_is_the_songs_own_and_rollouts_of_one_song_reach_it():
  model, vqs, _ = load_models(TINY)
  rng = np.random.default_rng(2)
  toks = _clips(model.cfg, 80, rng)
  toks[2]["upper"] = np.repeat(toks[2]["upper"][::4], 4)[:80]  # style 0, a slower song than c0
  target = EnergyTarget(vqs, toks, steps=8, rng=rng, windows=64)

  def windows(t):
    with torch.no_grad():
      d = vqs["upper"].denormalise(vqs["upper"].decode_codes(torch.as_tensor(t["upper"])[None].long()))[0]
    return torch.stack([d[o:o + 32] for o in range(16, len(d) - 31, 4)])
  own, _ = target.loss("upper", 0, windows(toks[0]), song="c0")
  other, _ = target.loss("upper", 0, windows(toks[2]), song="c0")
  assert float(own) < 1e-3 < 0.2 < float(other)  # (the spread term sees the 1e-3 floor)
  loss, _ = rollouts(model, vqs, toks, target, rng, torch.Generator().manual_seed(0), per_style=2, prefix=6,
                     steps=8, per_song=True)
  assert torch.isfinite(loss)


def test_bad_settings_are_clear_errors(tmp_path):
  import pytest
  from training.experiments.free_run_tune import main
  base = ["--model", TINY, "--tokens", str(tmp_path / "none.pt"), "--out", str(tmp_path / "o.dncw")]
  for flag, bad in (("--iters", "0"), ("--per-style", "0"), ("--prefix", "0"), ("--steps", "1"),
                    ("--lr", "0"), ("--own-weight", "-1")):
    with pytest.raises(SystemExit) as e:
      main(base + [flag, bad])
    assert e.value.code == 2
