"""SGMD's Python side (docs/diffusion.md): the motion vector and canonical frame invert exactly, the sampler
keeps known values, long dances agree on their overlaps, a training step moves the weights and the loss
terms are finite, and a model survives export and load."""
import numpy as np
import torch

from training.diffusion import motion
from training.diffusion.data import Song, Stats, WindowData
from training.diffusion.export import export_sgmd, load_sgmd
from training.diffusion.fixtures import _walk
from training.diffusion.sample import dance, ddim_timesteps, ddim_window
from training.diffusion.train import losses
from training.model.sgmd import SGMD, SGMDConfig

TINY = dict(d_model=16, n_heads=2, n_layers=1, n_music_layers=1, frames=8, style_dim=4, n_styles=2, dropout=0.0)


def test_motion_vector_inverts_and_the_frame_round_trips():
  p = _walk(20)
  yaw, origin = motion.frame_of(p[0])
  local = motion.positions_in_frame(p, yaw, origin)
  assert abs(local[0, 0, 0]) < 1e-12 and abs(local[0, 0, 2]) < 1e-12
  assert abs(motion.frame_of(local[0])[0]) < 1e-9            # faces +Z in its own frame
  v = motion.motion_vector(local)
  assert v.shape == (20, motion.POSE_DIM)
  np.testing.assert_allclose(motion.positions_of(v), local, atol=1e-9)
  np.testing.assert_allclose(motion.positions_from_frame(local, yaw, origin), p, atol=1e-9)
  moving = motion.contacts(p)
  assert set(np.unique(moving)) <= {0.0, 1.0}


def test_ddim_timesteps_match_the_contract():
  assert ddim_timesteps(1000, 5) == [999, 749, 500, 250, 0]
  assert ddim_timesteps(1000, 1) == [999]


def _model(seed=0):
  torch.manual_seed(seed)
  return SGMD(SGMDConfig(**TINY)).eval()


def test_sampler_keeps_known_values_exactly():
  m = _model()
  cfg = m.cfg
  g = torch.Generator().manual_seed(1)
  music = torch.randn(1, cfg.tokens, cfg.music_dim, generator=g)
  c = m.encode_music(music, torch.ones(1, dtype=torch.bool))
  style = torch.zeros(1, cfg.n_styles + 1)
  style[0, 0] = 1.0
  noise = torch.randn(cfg.frames, cfg.pose_dim, generator=g)
  known = torch.randn(cfg.frames, cfg.pose_dim, generator=g)
  mask = torch.zeros(cfg.frames, cfg.pose_dim)
  mask[:3] = 1.0
  mask[:, :3] = 1.0
  x = ddim_window(m, c, m.music_null[None], style, noise, 4, 2.0, known, mask)
  assert torch.equal(x[mask.bool()], known[mask.bool()])
  free = ddim_window(m, c, m.music_null[None], style, noise, 4, 2.0)
  assert not torch.allclose(free[mask.bool()], known[mask.bool()])


def _stats(cfg):
  rng = np.random.default_rng(0)
  return Stats(rng.normal(0, 0.1, cfg.pose_dim), np.full(cfg.pose_dim, 0.5), np.zeros(cfg.feature_dim),
               np.ones(cfg.feature_dim))


def test_a_long_dance_agrees_on_its_overlaps():
  m = _model()
  cfg = m.cfg
  rng = np.random.default_rng(2)
  feats = rng.normal(0, 1, (30, cfg.feature_dim)).astype(np.float32)
  pre = rng.uniform(-1, 1, (30, cfg.pre_dim)).astype(np.float32)
  meta = {"styles": ["a", "b"]}
  pos = dance(m, _stats(cfg), feats, pre, "a", meta, seed=0, steps=3, overlap=4)
  assert pos.shape == (30, 24, 3) and np.all(np.isfinite(pos))
  # Window 2 starts at frame 4 and knows frames 4..7 of window 1: the dance there is window 1's.
  again = dance(m, _stats(cfg), feats[:8], pre[:8], "a", meta, seed=0, steps=3, overlap=4)
  np.testing.assert_allclose(pos[:8], again, atol=1e-5)


def test_training_step_moves_the_weights_and_losses_are_finite():
  m = SGMD(SGMDConfig(**TINY))
  cfg = m.cfg
  rng = np.random.default_rng(3)
  songs = [Song(f"s{i}", i % 2, _walk(40), rng.normal(0, 1, (40, cfg.feature_dim)),
                rng.uniform(-1, 1, (40, cfg.pre_dim))) for i in range(3)]
  data = WindowData(songs, cfg.frames, cfg.frames_per_token)
  stats = data.stats(rng, n=20)
  x0, music, style = (torch.from_numpy(a) for a in data.batch(rng, 4, stats))
  t = torch.randint(0, cfg.diffusion_steps, (4,))
  abar = m.alphas_cumprod[t][:, None, None]
  xt = abar.sqrt() * x0 + (1 - abar).sqrt() * torch.randn_like(x0)
  sw = torch.nn.functional.one_hot(style, cfg.n_styles + 1).float()
  pred = m(xt, t, music, sw, torch.tensor([True, False, True, True]))
  d = losses(pred, x0, torch.from_numpy(stats.pose_mean).float(), torch.from_numpy(stats.pose_std).float())
  assert all(torch.isfinite(v) for v in d.values())
  before = m.out.weight.clone()
  opt = torch.optim.AdamW(m.parameters(), lr=1e-2)
  (d["diffusion"] + d["joints"]).backward()
  opt.step()
  assert not torch.equal(before, m.out.weight)


def test_export_and_load_give_the_same_model(tmp_path):
  m = _model(4)
  stats = _stats(m.cfg)
  path = tmp_path / "m.dncw"
  export_sgmd(str(path), m, stats, ["a", "b"], {"model_id": "t"}, weights_dtype="f32")
  m2, stats2, meta = load_sgmd(str(path))
  assert meta["kind"] == "sgmd" and meta["model_id"] == "t" and meta["styles"] == ["a", "b"]
  np.testing.assert_allclose(stats2.pose_std, stats.pose_std, rtol=1e-6)
  cfg = m.cfg
  g = torch.Generator().manual_seed(5)
  args = (torch.randn(1, cfg.frames, cfg.pose_dim, generator=g), torch.tensor([321]),
          torch.randn(1, cfg.tokens, cfg.music_dim, generator=g), torch.tensor([[0.0, 1.0, 0.0]]),
          torch.tensor([True]))
  with torch.no_grad():
    assert torch.allclose(m(*args), m2(*args), atol=1e-6)


def test_v_prediction_copies_a_clean_input_and_its_loss_is_the_v_error():
  torch.manual_seed(2)
  m = SGMD(SGMDConfig(**{**TINY, "prediction": "v"})).eval()
  cfg = m.cfg
  x0 = torch.randn(2, cfg.frames, cfg.pose_dim)
  eps = torch.randn_like(x0)
  music = torch.randn(2, cfg.tokens, cfg.music_dim)
  sw = torch.nn.functional.one_hot(torch.tensor([0, 2]), cfg.n_styles + 1).float()
  keep = torch.tensor([True, True])
  with torch.no_grad():
    for t in (0, 500, 999):
      tt = torch.tensor([t, t])
      a = m.alphas_cumprod[t]
      xt = a.sqrt() * x0 + (1 - a).sqrt() * eps
      pred = m(xt, tt, music, sw, keep)
      # x0_hat = sqrt(abar) x_t - sqrt(1 - abar) out: at t = 0 it is x_t up to sqrt(1 - abar_0) ~ 0.006
      if t == 0:
        assert torch.max(torch.abs(pred - xt)).item() < 0.1
      v = a.sqrt() * eps - (1 - a).sqrt() * x0
      v_hat = (a.sqrt() * xt - pred) / (1 - a).sqrt()
      d = losses(pred, x0, torch.zeros(cfg.pose_dim), torch.ones(cfg.pose_dim), noise_std=(1 - a).sqrt().expand(2))
      assert abs(d["diffusion"].item() - torch.mean((v_hat - v) ** 2).item()) < 1e-3 * max(1.0, d["diffusion"].item())
