#include "engine/audio/beat_tracker.h"

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <vector>

namespace dance::engine::audio {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kFramesPerMinute = 60.0 * kFrameRate;  // 1800
constexpr double kScoreDecay = 0.9945;                  // exp(-1 / (6 s * 30 fps))
constexpr double kContinuityBonus = 1.3;    // favours tempi within 4 % of the running tempo
constexpr double kPhaseDecayFrames = 45.0;  // 1.5 s
constexpr double kPllGain = 0.15;
constexpr double kTempoSmoothing = 0.1;  // per frame, once locked
// Tempo prior: log-normal around 120 BPM. 0.6 octave (narrower than librosa's 1.0) was chosen on
// the tang2018 dance songs, where 1.0 picked the eighth-note rate of cha-cha (~250 BPM); see
// docs/features.md.
constexpr double kPriorOctaves = 0.6;

// Constant tables shared by all trackers.
struct Tables {
  std::array<float, kTempoWindowFrames> hann;
  std::array<double, kTempoGridSize> grid_bpm;
  std::array<double, kTempoGridSize> prior;
  // Fourier basis (2 * kTempoGridSize, kTempoWindowFrames), row-major: row 2g = cos, row 2g + 1 =
  // sin.
  std::vector<float> basis;
  std::array<float, kTempoWindowFrames> phase_weight;
  std::array<double, kNumTempogram> tempogram_lag;
};

const Tables& GetTables() {
  static const Tables* tables = [] {
    auto* t = new Tables;
    for (int a = 0; a < kTempoWindowFrames; ++a) {
      t->hann[a] =
          static_cast<float>(0.5 - 0.5 * std::cos(2.0 * kPi * (a + 0.5) / kTempoWindowFrames));
      t->phase_weight[a] = static_cast<float>(std::exp(-a / kPhaseDecayFrames));
    }
    const double ratio = std::pow(kTempoGridMaxBpm / kTempoGridMinBpm, 1.0 / (kTempoGridSize - 1));
    t->basis.resize(2 * kTempoGridSize * kTempoWindowFrames);
    for (int g = 0; g < kTempoGridSize; ++g) {
      const double bpm = kTempoGridMinBpm * std::pow(ratio, g);
      t->grid_bpm[g] = bpm;
      const double z = std::log2(bpm / 120.0) / kPriorOctaves;
      t->prior[g] = std::exp(-0.5 * z * z);
      const double f = bpm / kFramesPerMinute;
      for (int a = 0; a < kTempoWindowFrames; ++a) {
        t->basis[(2 * g) * kTempoWindowFrames + a] =
            static_cast<float>(std::cos(2.0 * kPi * f * a));
        t->basis[(2 * g + 1) * kTempoWindowFrames + a] =
            static_cast<float>(std::sin(2.0 * kPi * f * a));
      }
    }
    const double tg_ratio =
        std::pow(kTempogramMaxBpm / kTempogramMinBpm, 1.0 / (kNumTempogram - 1));
    for (int i = 0; i < kNumTempogram; ++i) {
      t->tempogram_lag[i] = kFramesPerMinute / (kTempogramMinBpm * std::pow(tg_ratio, i));
    }
    return t;
  }();
  return *tables;
}

double Wrap(double x) { return x - std::floor(x); }  // to [0, 1)

// Sum over harmonics h (below 0.45 cycles per frame) of |sum_a y_a exp(-i 2 pi h f a)|, f = bpm /
// 1800.
// The four harmonics' recurrences are independent: they advance together in 4-wide vectors (AVX2 with
// -march=x86-64-v3, two SSE2 halves otherwise). Each lane does exactly the scalar recurrence's
// operations in the same order (no FMA: -ffp-contract=off), so the sum is bit-identical to computing
// the harmonics one after another; only the latency chains overlap.
double HarmonicSum(const std::array<float, kTempoWindowFrames>& y, double bpm) {
  using V4 = double __attribute__((vector_size(32)));
  int harmonics = 0;
  V4 cr = {1.0, 1.0, 1.0, 1.0}, ci = {0.0, 0.0, 0.0, 0.0};
  for (int h = 1; h <= 4; ++h) {
    const double f = h * bpm / kFramesPerMinute;
    if (f > 0.45) break;
    harmonics = h;
    // Real arithmetic: std::complex multiplication calls __muldc3 (NaN/Inf handling) without
    // fast-math.
    cr[h - 1] = std::cos(2.0 * kPi * f);
    ci[h - 1] = -std::sin(2.0 * kPi * f);
  }
  V4 rr = {1.0, 1.0, 1.0, 1.0}, ri = {0.0, 0.0, 0.0, 0.0}, ar = ri, ai = ri;
  for (int a = 0; a < kTempoWindowFrames; ++a) {
    const double ya = y[a];
    const V4 v = {ya, ya, ya, ya};
    ar += v * rr;
    ai += v * ri;
    const V4 nr = rr * cr - ri * ci;
    ri = rr * ci + ri * cr;
    rr = nr;
  }
  double total = 0.0;
  for (int h = 0; h < harmonics; ++h) total += std::sqrt(ar[h] * ar[h] + ai[h] * ai[h]);
  return total;
}

// Golden-section search for the harmonic-sum maximum within +-3 % of `bpm`.
double RefineTempo(const std::array<float, kTempoWindowFrames>& y, double bpm) {
  constexpr double kInvPhi = 0.6180339887498949;
  double lo = bpm * 0.97, hi = bpm * 1.03;
  double x1 = hi - kInvPhi * (hi - lo), x2 = lo + kInvPhi * (hi - lo);
  double f1 = HarmonicSum(y, x1), f2 = HarmonicSum(y, x2);
  for (int i = 0; i < 14; ++i) {
    if (f1 < f2) {
      lo = x1;
      x1 = x2;
      f1 = f2;
      x2 = lo + kInvPhi * (hi - lo);
      f2 = HarmonicSum(y, x2);
    } else {
      hi = x2;
      x2 = x1;
      f2 = f1;
      x1 = hi - kInvPhi * (hi - lo);
      f1 = HarmonicSum(y, x1);
    }
  }
  return 0.5 * (lo + hi);
}

}  // namespace

BeatTracker::BeatTracker() { GetTables(); }

void BeatTracker::Update(float onset, BeatTrackerOutput* out) {
  const Tables& t = GetTables();
  BeatTrackerState& s = state_;
  s.onset_ring[s.frames % kTempoWindowFrames] = onset;
  ++s.frames;

  // Trailing envelope by age (0 = this frame); frames before the stream start are 0.
  double mean = 0.0;
  const int newest = static_cast<int>((s.frames - 1) % kTempoWindowFrames);
  const int available = static_cast<int>(std::min<int64_t>(s.frames, kTempoWindowFrames));
  for (int a = 0; a < kTempoWindowFrames; ++a) {
    const int slot = newest - a < 0 ? newest - a + kTempoWindowFrames : newest - a;
    y_[a] = a < available ? s.onset_ring[slot] : 0.0f;
    mean += y_[a];
  }
  mean /= kTempoWindowFrames;
  double abs_sum = 0.0, phase_abs_sum = 0.0;
  double zr = 0.0, zi = 0.0;  // recent Fourier component (filled after the tempo is known)
  std::array<float, kTempoWindowFrames> yw;  // Hann-windowed (stack scratch, no allocation)
  for (int a = 0; a < kTempoWindowFrames; ++a) {
    y_[a] = static_cast<float>(y_[a] - mean);
    yw[a] = y_[a] * t.hann[a];
    abs_sum += std::fabs(yw[a]);
  }

  // Autocorrelation of the windowed envelope.
  const Eigen::Map<const Eigen::VectorXf> ywv(yw.data(), kTempoWindowFrames);
  for (int lag = 0; lag <= kMaxAcfLag + 1; ++lag) {
    const int n = kTempoWindowFrames - lag;
    acf_[lag] = ywv.head(n).dot(ywv.segment(lag, n));
  }
  const double inv0 = acf_[0] > 1e-9 ? 1.0 / acf_[0] : 0.0;
  auto r_at = [&](double lag) {
    const int l0 = static_cast<int>(lag);
    const double frac = lag - l0;
    return ((1.0 - frac) * acf_[l0] + frac * acf_[l0 + 1]) * inv0;
  };
  for (int i = 0; i < kNumTempogram; ++i)
    out->tempogram[i] = static_cast<float>(r_at(t.tempogram_lag[i]));

  // Tempo scores: ACF x Fourier magnitude x prior, smoothed over time.
  const double inv_abs = abs_sum > 1e-9 ? 1.0 / abs_sum : 0.0;
  int best = 0;
  // All grid tempi at once: one matrix-vector product (vectorised by Eigen; fixed order,
  // deterministic).
  using BasisMatrix = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
  Eigen::Map<const BasisMatrix> basis(t.basis.data(), 2 * kTempoGridSize, kTempoWindowFrames);
  Eigen::Map<Eigen::VectorXf>(projection_.data(), 2 * kTempoGridSize).noalias() =
      basis * Eigen::Map<const Eigen::VectorXf>(yw.data(), kTempoWindowFrames);
  for (int g = 0; g < kTempoGridSize; ++g) {
    const float re = projection_[2 * g], im = projection_[2 * g + 1];
    const double fourier = 2.0 * std::sqrt(double(re) * re + double(im) * im) * inv_abs;
    // The envelope is sampled at 30 fps, so a click train's autocorrelation peaks at the integer
    // lags around its period; taking the larger neighbour keeps that from biasing the tempo (the
    // Fourier magnitude locates the peak, the autocorrelation only rejects tempo multiples).
    const double lag = kFramesPerMinute / t.grid_bpm[g];
    const int lag0 = static_cast<int>(lag);
    const double acf = std::max(0.0, std::max(acf_[lag0], acf_[lag0 + 1]) * inv0);
    const double score = acf * std::min(1.0, fourier) * t.prior[g];
    s.score[g] = static_cast<float>(kScoreDecay * s.score[g] + (1.0 - kScoreDecay) * score);
  }
  // Hysteresis: a tempo near the running one wins unless another is clearly stronger.
  double best_value = -1.0;
  // |log(ratio)| < 0.04 without a log per grid tempo: ratios clearly inside or outside
  // (exp(+-0.04), with a 1e-9 relative margin, far above log's rounding error) are decided directly,
  // only the rare ones at the boundary evaluate the log. Same decisions as the log everywhere.
  static const double kNearLo = std::exp(-0.04), kNearHi = std::exp(0.04);
  auto is_near = [&s](double grid_bpm) {
    const double ratio = grid_bpm / s.tempo_bpm;
    if (ratio < kNearLo * (1.0 - 1e-9) || ratio > kNearHi * (1.0 + 1e-9)) return false;
    if (ratio > kNearLo * (1.0 + 1e-9) && ratio < kNearHi * (1.0 - 1e-9)) return true;
    return std::fabs(std::log(ratio)) < 0.04;
  };
  // Octave classes first: the tempo clock folds octaves, so a tempo and its octaves are one choice
  // for the dance, and their summed score decides between metrical levels that are not octaves of
  // each other (3/2, 4/3), which a single octave's score can tip under time-stretching. Then the best
  // octave of the winning class (the tempo clock and the beat phase still need one). The running
  // tempo's class, and then its octave, get the continuity bonus.
  const double grid_per_octave =
      (kTempoGridSize - 1) / std::log2(kTempoGridMaxBpm / kTempoGridMinBpm);  // ~69.6
  auto score_at = [&s](double x) {  // linear interpolation on the grid; 0 outside
    if (x < 0.0 || x > kTempoGridSize - 1) return 0.0;
    const int i = std::min(static_cast<int>(x), kTempoGridSize - 2);
    const double frac = x - i;
    return (1.0 - frac) * s.score[i] + frac * s.score[i + 1];
  };
  const double running_pos =
      s.tempo_locked ? std::log2(s.tempo_bpm / kTempoGridMinBpm) * grid_per_octave : 0.0;
  auto near_class = [&](int g) {  // within 0.04 (natural log) of the running tempo, up to octaves
    if (!s.tempo_locked) return false;
    const double octaves = (g - running_pos) / grid_per_octave;
    return std::fabs(octaves - std::round(octaves)) * std::log(2.0) < 0.04;
  };
  int best_class = 0;
  for (int g = 0; g < kTempoGridSize; ++g) {
    double sum = 0.0;
    for (int k = -3; k <= 3; ++k) sum += k == 0 ? s.score[g] : score_at(g + k * grid_per_octave);
    const double value = sum * (near_class(g) ? kContinuityBonus : 1.0);
    if (value > best_value) {
      best_value = value;
      best_class = g;
    }
  }
  best = best_class;
  best_value = -1.0;
  for (int k = -3; k <= 3; ++k) {
    const int g = static_cast<int>(std::lround(best_class + k * grid_per_octave));
    if (g < 0 || g >= kTempoGridSize) continue;
    const bool near = s.tempo_locked && is_near(t.grid_bpm[g]);
    const double value = s.score[g] * (near ? kContinuityBonus : 1.0);
    if (value > best_value) {
      best_value = value;
      best = g;
    }
  }
  if (s.score[best] > 1e-6) {
    double offset = 0.0;  // parabolic refinement in grid (log-tempo) units
    if (best > 0 && best + 1 < kTempoGridSize) {
      const double l = s.score[best - 1], m = s.score[best], r = s.score[best + 1];
      const double denom = l - 2.0 * m + r;
      if (denom < 0.0) offset = std::clamp(0.5 * (l - r) / denom, -0.5, 0.5);
    }
    const double coarse = t.grid_bpm[best] * std::pow(kTempoGridMaxBpm / kTempoGridMinBpm,
                                                      offset / (kTempoGridSize - 1));
    // The scores choose the tempo octave but their peak is broad (8 s window) and pulled by the
    // prior. Refine on the envelope's harmonic sum, whose peak is h times sharper at harmonic h.
    const double refined = std::clamp(RefineTempo(yw, coarse), kTempoGridMinBpm, kTempoGridMaxBpm);
    if (!s.tempo_locked || std::fabs(std::log(coarse / s.tempo_bpm)) > 0.06) {
      s.tempo_bpm = refined;  // first estimate or a real tempo change: jump
      s.tempo_locked = true;
    } else {
      s.tempo_bpm += kTempoSmoothing * (refined - s.tempo_bpm);
    }
  }
  const double f = s.tempo_bpm / kFramesPerMinute;  // beats per frame

  // Measured phase: recent onsets, exponentially weighted, at the running tempo.
  const double cr = std::cos(2.0 * kPi * f), ci = -std::sin(2.0 * kPi * f);
  double rr = 1.0, ri = 0.0;  // exp(-i 2 pi f a) by recurrence
  for (int a = 0; a < kTempoWindowFrames; ++a) {
    const double v = static_cast<double>(y_[a]) * t.phase_weight[a];
    zr += v * rr;
    zi += v * ri;
    const double nr = rr * cr - ri * ci;
    ri = rr * ci + ri * cr;
    rr = nr;
    phase_abs_sum += std::fabs(v);
  }
  // Onsets at ages a = d + k/f give Z ~ exp(-i 2 pi f d): phase since the beat = -arg(Z) / 2 pi.
  const double magnitude = std::sqrt(zr * zr + zi * zi);
  const double confidence =
      phase_abs_sum > 1e-9 ? std::min(1.0, 2.0 * magnitude / phase_abs_sum) : 0.0;
  const double measured = Wrap(-std::atan2(zi, zr) / (2.0 * kPi) + kOnsetDelayFrames * f);

  // Phase-locked loop: advance by the tempo, pull towards the measurement, never step backwards.
  const double predicted = s.phase + f;
  double err = Wrap(measured - predicted + 0.5) - 0.5;
  const double gain = kPllGain * std::min(1.0, confidence / 0.3);
  const double step = std::clamp(f + gain * err, 0.5 * f, 1.5 * f);
  double phase = s.phase + step;
  out->beat = false;
  if (phase >= 1.0) {
    phase -= std::floor(phase);
    ++s.beat_count;
    out->beat = true;
    out->beat_offset_frames = phase / step;
  }
  s.phase = phase;
  out->tempo_bpm = s.tempo_bpm;
  out->beat_phase = s.phase;
  out->bar_phase = (static_cast<double>(s.beat_count % 4) + s.phase) / 4.0;
  out->confidence = confidence;
}

}  // namespace dance::engine::audio
