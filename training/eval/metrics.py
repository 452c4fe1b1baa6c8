"""Dance metrics: FID_k/FID_g, Div_k/Div_g, BAS (+ chance), PFC, jitter, foot skating, bone lengths.

All take global positions (T, 24, 3) in metres at `fps` (30), Y up, floor at y = 0. docs/evaluation.md
defines each one and gives the reference numbers.

Usage:
  ref = FeatureStats.fit(real_validation_features)            # normaliser
  fid = frechet_distance(ref.apply(real_train), ref.apply(generated))
  bas = beat_align_score(music_beats_s, motion_beats(positions, fps, t0))
"""
from __future__ import annotations

import dataclasses

import numpy as np
from scipy import linalg
from scipy.ndimage import gaussian_filter1d
from scipy.signal import argrelextrema

from training.data.representation import facing_yaw
from training.data.skeleton import FOOT_JOINTS, J

BAS_SIGMA_S = 0.1           # Gaussian tolerance of BAS (3 frames at 30 fps, Bailando's 3 frames)
CONTACT_HEIGHT = 0.05       # a foot joint lower than this (m) is in contact with the floor
CONTACT_SPEED = 0.5         # ... and slower than this vertically (m/s)


@dataclasses.dataclass
class FeatureStats:
  """Per-dimension mean/std used to normalise features before FID and Div."""
  mean: np.ndarray
  std: np.ndarray

  @classmethod
  def fit(cls, feats: np.ndarray, floor: float | None = None) -> "FeatureStats":
    """floor: smallest std a dimension may have (default: 5 % of the median std over dimensions), so a
    dimension that hardly varies in the real data (a rigid hip's energy, a pose nobody takes) cannot
    dominate the distance when another set varies on it."""
    std = feats.std(0)
    if floor is None:
      floor = 0.05 * float(np.median(std))
    return cls(feats.mean(0), np.maximum(std, max(floor, 1e-8)))

  def apply(self, feats: np.ndarray) -> np.ndarray:
    return (feats - self.mean) / self.std


def frechet_parts(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
  """frechet_distance(a, b) split into its mean term ||mu_a - mu_b||^2 (the sets' averages differ) and its
  covariance term (their spreads and correlations differ); the two sum to the distance."""
  mean_term = float(((a.mean(0) - b.mean(0)) ** 2).sum())
  return mean_term, frechet_distance(a, b) - mean_term


def frechet_distance(a: np.ndarray, b: np.ndarray) -> float:
  """Frechet distance between Gaussians fitted to the rows of a and b (N, D)."""
  mu1, mu2 = a.mean(0), b.mean(0)
  s1, s2 = np.cov(a, rowvar=False), np.cov(b, rowvar=False)
  covmean, _ = linalg.sqrtm(s1 @ s2, disp=False)
  if not np.isfinite(covmean).all():
    eps = 1e-6 * np.eye(len(mu1))
    covmean = linalg.sqrtm((s1 + eps) @ (s2 + eps))
  covmean = covmean.real
  return float(((mu1 - mu2) ** 2).sum() + np.trace(s1) + np.trace(s2) - 2 * np.trace(covmean))


def diversity(feats: np.ndarray) -> float:
  """Mean pairwise Euclidean distance between the rows (N, D) (normalised features)."""
  n = len(feats)
  if n < 2:
    return float("nan")
  d = np.linalg.norm(feats[:, None] - feats[None], axis=-1)
  return float(d.sum() / (n * (n - 1)))


def joint_speed(positions: np.ndarray, fps: float = 30.0, sigma: float = 2.0) -> np.ndarray:
  """Mean joint speed (m/s) per frame (T,), root-relative joints plus the root, Gaussian-smoothed."""
  p = np.asarray(positions, dtype=np.float64)
  v = np.linalg.norm(np.gradient(p, axis=0), axis=-1) * fps
  s = v.mean(1)
  return gaussian_filter1d(s, sigma) if sigma > 0 else s


def motion_beats(positions: np.ndarray, fps: float = 30.0, sigma: float = 2.0) -> np.ndarray:
  """Motion beats: local minima of the smoothed mean joint speed, in seconds from the first frame."""
  s = joint_speed(positions, fps, sigma)
  idx = argrelextrema(s, np.less)[0]
  return idx / fps


def beat_align_score(music_beats: np.ndarray, motion_beats_s: np.ndarray,
                     sigma: float = BAS_SIGMA_S) -> float:
  """Bailando's BAS: mean over music beats of exp(-d^2 / (2 sigma^2)), d = distance to the nearest
  motion beat. Only music beats inside the motion's time span count."""
  mb = np.asarray(motion_beats_s)
  if len(mb) == 0 or len(music_beats) == 0:
    return 0.0
  d = np.abs(np.asarray(music_beats)[:, None] - mb[None]).min(1)
  return float(np.exp(-d ** 2 / (2 * sigma ** 2)).mean())


def beat_align_chance(music_beats: np.ndarray, motion_beats_s: np.ndarray, n: int = 50,
                      seed: int = 0, sigma: float = BAS_SIGMA_S) -> float:
  """BAS against the music beats shifted by random offsets, uniform over one median beat interval."""
  if len(music_beats) < 2:
    return float("nan")
  ibi = float(np.median(np.diff(music_beats)))
  rng = np.random.default_rng(seed)
  return float(np.mean([beat_align_score(music_beats + rng.uniform(0, ibi), motion_beats_s, sigma)
                        for _ in range(n)]))


def beats_in_span(beats_s: np.ndarray, start_s: float, duration_s: float) -> np.ndarray:
  """Music beats (song time) inside [start, start + duration), re-expressed from the segment start."""
  b = np.asarray(beats_s, dtype=np.float64) - start_s
  return b[(b >= 0) & (b < duration_s)]


def pfc(positions: np.ndarray, fps: float = 30.0) -> float:
  """Physical foot contact score (EDGE's idea, our code): mean over frames of the pelvis's horizontal
  acceleration (normalised by its max over the segment) times the slower foot's speed (each foot's
  speed normalised by its max over the segment). High when the body accelerates with no foot planted.
  Lower is better."""
  p = np.asarray(positions, dtype=np.float64)
  dt = 1.0 / fps
  root_a = np.linalg.norm((np.gradient(np.gradient(p[:, 0], dt, axis=0), dt, axis=0))[:, [0, 2]],
                          axis=-1)
  feet = []
  for a, b in ((J["left_ankle"], J["left_foot"]), (J["right_ankle"], J["right_foot"])):
    v = np.linalg.norm(np.gradient(p[:, [a, b]], dt, axis=0), axis=-1).mean(1)
    feet.append(v / (v.max() + 1e-9))
  return float((root_a / (root_a.max() + 1e-9) * np.minimum(feet[0], feet[1])).mean())


def jitter(positions: np.ndarray, fps: float = 30.0) -> float:
  """Mean jerk magnitude over joints and frames (m/s^3): third finite difference * fps^3."""
  p = np.asarray(positions, dtype=np.float64)
  return float(np.linalg.norm(np.diff(p, n=3, axis=0), axis=-1).mean() * fps ** 3)


def foot_skating(positions: np.ndarray, fps: float = 30.0) -> float:
  """Mean horizontal speed (m/s) of foot joints while in contact (lower than CONTACT_HEIGHT and slower
  than CONTACT_SPEED vertically). Real dancers pivot and slide a little; lower is better."""
  p = np.asarray(positions, dtype=np.float64)
  v = np.gradient(p[:, list(FOOT_JOINTS)], axis=0) * fps           # (T, 4, 3)
  contact = (p[:, list(FOOT_JOINTS), 1] < CONTACT_HEIGHT) & (np.abs(v[..., 1]) < CONTACT_SPEED)
  if not contact.any():
    return float("nan")
  return float(np.linalg.norm(v[..., [0, 2]], axis=-1)[contact].mean())


def contact_fraction(positions: np.ndarray) -> float:
  p = np.asarray(positions, dtype=np.float64)
  return float((p[:, list(FOOT_JOINTS), 1].min(1) < CONTACT_HEIGHT).mean())


def bone_length_error(positions: np.ndarray, parents: np.ndarray, lengths: np.ndarray) -> dict:
  """Bone-length consistency: mean |length - canonical| (mm), max (mm), and the mean over bones of the
  length's coefficient of variation over time (%)."""
  p = np.asarray(positions, dtype=np.float64)
  bl = np.linalg.norm(p[:, 1:] - p[:, parents[1:]], axis=-1)
  err = np.abs(bl - lengths[1:])
  cv = bl.std(0) / (bl.mean(0) + 1e-9)
  return {"bone_err_mm": float(err.mean() * 1000), "bone_err_max_mm": float(err.max() * 1000),
          "bone_cv_pct": float(cv.mean() * 100)}


def turn_rate(positions: np.ndarray, fps: float = 30.0) -> float:
  """Mean absolute turning speed of the body's facing (hips and shoulders), rad/s."""
  yaw = np.unwrap(facing_yaw(np.asarray(positions, dtype=np.float64)))
  if len(yaw) < 2:
    return 0.0
  return float(np.abs(np.diff(yaw)).mean() * fps)
