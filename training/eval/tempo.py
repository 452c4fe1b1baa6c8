"""Motion periodicity and tempo following.

The dominant period of a dance is the lag of the highest peak of the autocorrelation of its mean joint
speed (0.3-4 s; the shortest lag whose peak is within 10 % of the highest, since multiples of a period peak
as high), refined by a parabola through the peak. Tempo following time-stretches the music
(sox tempo 0.85 / 1.15), lets a generator dance to each version and fits how the dance's period scales:
  ratio = sum_f x_f y_f / sum_f x_f^2,  x_f = log(1 / f) (the music's period change), y_f = log(P_f / P_1)
so 1 = the dance's period follows the music exactly, 0 = it ignores the music. After the original's
period P_1 is found, P_f is searched within [0.7, 1.4] x P_1: that window holds both outcomes (ignore:
P_1; follow: P_1 / f), so it does not favour either, and it keeps octave jumps out.

Usage:
  p = dominant_period(positions)                                 # seconds
  r = tempo_following(generate, "song.ogg", workdir="/tmp/tf")   # generate(audio_path) -> (T, 24, 3)
  c = perfect_follower_ratio(seed0, [seed1, seed2])                # what the per-run statistic can reach
  cs = section_follower_ratios(real_positions, window_s=30)        # the same, a real dancer's sections as draws
"""
from __future__ import annotations

import pathlib
from collections.abc import Callable

import numpy as np

from training.eval.metrics import joint_speed
from training.eval.music import stretch_audio

FACTORS = (0.85, 1.15)
PEAK_TOLERANCE = 0.1


def speed_autocorrelation(positions: np.ndarray, fps: float = 30.0, max_lag_s: float = 4.5) -> np.ndarray:
  s = joint_speed(positions, fps, sigma=1.0)
  s = s - s.mean()
  n = len(s)
  max_lag = min(int(max_lag_s * fps), n - 1)
  denom = (s * s).sum() + 1e-12
  return np.array([(s[:n - k] * s[k:]).sum() / denom * n / (n - k) for k in range(max_lag + 1)])


def dominant_period(positions: np.ndarray, fps: float = 30.0, lo_s: float = 0.3, hi_s: float = 4.0,
                    around_s: float | None = None, window: tuple[float, float] = (0.7, 1.4)) -> float:
  """Lag (s) of the dominant local maximum of the speed autocorrelation within [lo, hi] (or within
  window x around_s when given); NaN if there is none."""
  if around_s is not None:
    lo_s, hi_s = window[0] * around_s, window[1] * around_s
  return period_of_autocorrelation(speed_autocorrelation(positions, fps, max_lag_s=hi_s + 0.2), fps, lo_s, hi_s)


def period_of_autocorrelation(ac: np.ndarray, fps: float, lo_s: float, hi_s: float) -> float:
  """The dominant-period rule of dominant_period applied to a given speed autocorrelation (e.g. the mean
  over several dances of one song); NaN if there is no peak in [lo_s, hi_s]."""
  k = np.arange(len(ac))
  peaks = [i for i in range(1, len(ac) - 1) if ac[i] >= ac[i - 1] and ac[i] > ac[i + 1]
           and lo_s * fps <= i <= hi_s * fps]
  if not peaks:
    return float("nan")
  # Multiples of a period peak as high as the period itself: take the shortest lag whose peak is within
  # PEAK_TOLERANCE of the highest one.
  top = max(ac[j] for j in peaks)
  i = min(j for j in peaks if ac[j] >= top - PEAK_TOLERANCE * abs(top))
  a, b, c = ac[i - 1], ac[i], ac[i + 1]
  den = a - 2 * b + c
  off = 0.5 * (a - c) / den if den != 0 else 0.0
  return float((k[i] + off) / fps)


def period_strength(positions: np.ndarray, period_s: float, fps: float = 30.0) -> float:
  """Autocorrelation of the speed at the given lag (1 = perfectly periodic)."""
  ac = speed_autocorrelation(positions, fps, max_lag_s=period_s + 0.1)
  x = period_s * fps
  i = int(np.floor(x))
  if i + 1 >= len(ac):
    return float("nan")
  return float(ac[i] + (x - i) * (ac[i + 1] - ac[i]))


def fit_ratio(factors, periods, base_period) -> float:
  x = np.log(1.0 / np.asarray(factors, dtype=np.float64))
  y = np.log(np.asarray(periods, dtype=np.float64) / base_period)
  ok = np.isfinite(y)
  if not ok.any():
    return float("nan")
  return float((x[ok] * y[ok]).sum() / (x[ok] ** 2).sum())


def tempo_following(generate: Callable[[str], np.ndarray], audio_path: str | pathlib.Path,
                    workdir: str | pathlib.Path, factors=FACTORS, fps: float = 30.0) -> dict:
  """Runs `generate` on the song and on its time-stretched versions; returns the periods and the ratio.

  generate(audio_path) must return positions (T, 24, 3) at fps, dancing to the whole file given.
  """
  workdir = pathlib.Path(workdir)
  base = generate(str(audio_path))
  p1 = dominant_period(base, fps)
  periods = []
  for f in factors:
    stretched = stretch_audio(audio_path, f, workdir / f"{pathlib.Path(audio_path).stem}_x{f:.2f}.wav")
    # No dominant period in the original (a dance without a periodic peak): nothing to follow.
    periods.append(dominant_period(generate(str(stretched)), fps, around_s=p1) if np.isfinite(p1)
                   else float("nan"))
  return {"base_period_s": p1, "factors": list(factors), "periods_s": periods,
          "ratio": fit_ratio(factors, periods, p1)}


def perfect_follower_ratio(base: np.ndarray, others: list[np.ndarray], factors=FACTORS, fps: float = 30.0) -> float:
  """The per-run statistic of tempo_following for an ideal follower whose dances vary between draws like
  the generator's: the base period from `base`; the dance to the music stretched by factors[i] is another
  draw (others[i]: same music, another seed, as in a real run where each version is danced anew) played
  exactly factors[i] times faster. 1 would need every draw to share one period; the gap to 1 is what the
  draw-to-draw spread of the period alone costs this statistic."""
  p1 = dominant_period(base, fps)
  if not np.isfinite(p1):
    return float("nan")
  periods = [dominant_period(time_stretch_motion(o, f), fps, around_s=p1) for o, f in zip(others, factors)]
  return fit_ratio(factors, periods, p1)


def section_follower_ratios(positions: np.ndarray, window_s: float = 30.0, hop_s: float = 10.0,
                            factors=FACTORS, fps: float = 30.0) -> list[float]:
  """perfect_follower_ratio with sections of one dance as the draws: the windows starting every hop_s
  seconds, each the base once and the next two (wrapping) its two stretched versions. Applied to a real
  dance, this is what a generator whose draws vary like the dancer's own sections would score on the
  per-run statistic (the dancer's variation from section to section plus the estimator's noise on
  window_s-long excerpts). Empty if the dance has fewer than three windows; NaN entries are dropped."""
  w = int(round(window_s * fps))
  starts = range(0, len(positions) - w + 1, int(round(hop_s * fps)))
  sections = [positions[a:a + w] for a in starts]
  n = len(sections)
  if n < 3:
    return []
  ratios = [perfect_follower_ratio(sections[i], [sections[(i + 1) % n], sections[(i + 2) % n]], factors, fps)
            for i in range(n)]
  return [r for r in ratios if np.isfinite(r)]


def time_stretch_motion(positions: np.ndarray, factor: float) -> np.ndarray:
  """The motion played `factor` times faster (linear interpolation), for baselines and tests."""
  t = len(positions)
  n = int(np.floor((t - 1) / factor)) + 1
  src = np.arange(n) * factor
  i = np.minimum(np.floor(src).astype(int), t - 2)
  w = (src - i)[:, None, None]
  return positions[i] * (1 - w) + positions[i + 1] * w


def pooled_tempo_following(generate_many: Callable[[str], list[np.ndarray]], audio_path: str | pathlib.Path,
                           workdir: str | pathlib.Path, factors=FACTORS, fps: float = 30.0,
                           max_lag_s: float = 6.0) -> dict:
  """tempo_following for a stochastic generator: generate_many(audio) returns several dances (seeds) of
  the same music; their speed autocorrelations are averaged before the dominant period is taken, so the
  period is that of the generator's dances to this music rather than of one random draw. Same fit."""
  workdir = pathlib.Path(workdir)

  def mean_ac(path):
    acs = [speed_autocorrelation(p, fps, max_lag_s=max_lag_s) for p in generate_many(str(path))]
    n = min(len(a) for a in acs)
    return np.mean([a[:n] for a in acs], axis=0)

  p1 = period_of_autocorrelation(mean_ac(audio_path), fps, 0.3, 4.0)
  periods = []
  for f in factors:
    stretched = stretch_audio(audio_path, f, workdir / f"{pathlib.Path(audio_path).stem}_x{f:.2f}.wav")
    periods.append(period_of_autocorrelation(mean_ac(stretched), fps, 0.7 * p1, 1.4 * p1) if np.isfinite(p1)
                   else float("nan"))
  return {"base_period_s": p1, "factors": list(factors), "periods_s": periods,
          "ratio": fit_ratio(factors, periods, p1)}
