#include "engine/audio/tempo_clock.h"

#include <algorithm>
#include <array>
#include <cmath>

namespace dance::engine::audio {

double TempoClock::Fold(double tempo_bpm) {
  const double ref = options_.reference_bpm;
  if (!std::isfinite(tempo_bpm) || tempo_bpm <= 0.0) tempo_bpm = ref;
  const double lo = ref / std::sqrt(2.0);
  const double hi = ref * std::sqrt(2.0);
  if (octave_set_) {
    // Hysteresis: a tempo hovering at an octave edge keeps its octave instead of flipping each frame.
    const double folded = std::ldexp(tempo_bpm, octave_);
    const double h = 1.0 + options_.octave_hysteresis;
    if (folded >= lo / h && folded < hi * h) return folded;
  }
  int octave = 0;
  double folded = tempo_bpm;
  while (folded < lo && octave < 8) {
    folded *= 2.0;
    ++octave;
  }
  while (folded >= hi && octave > -8) {
    folded *= 0.5;
    --octave;
  }
  octave_ = octave;
  octave_set_ = true;
  return folded;
}

TempoClock::Span TempoClock::Push(double tempo_bpm) {
  Span s;
  s.frame = frames_;
  s.rate = Fold(tempo_bpm) / options_.reference_bpm;
  s.begin = position_;
  s.end = position_ + s.rate;
  s.first_warped = next_warped_;
  // Warped frames j with begin <= j < end; next_warped_ == ceil(begin) already.
  int64_t end_warped = static_cast<int64_t>(std::ceil(s.end));
  if (end_warped < s.first_warped) end_warped = s.first_warped;
  s.end_warped = end_warped;
  next_warped_ = end_warped;
  position_ = s.end;
  ++frames_;
  return s;
}

double BarClockFrames(int beats_per_bar, double reference_bpm) {
  return beats_per_bar * 60.0 * kFrameRate / reference_bpm;
}

void BarClockPhase(int64_t warped_frame, double bar_frames, float* features) {
  const double x = static_cast<double>(warped_frame) / bar_frames;
  const double a = 2.0 * 3.14159265358979323846 * (x - std::floor(x));
  features[kBarPhaseCosIndex] = static_cast<float>(std::cos(a));
  features[kBarPhaseSinIndex] = static_cast<float>(std::sin(a));
}

void FoldTempoFeatures(double rate, float* features) {
  if (!(rate > 0.0) || !std::isfinite(rate)) return;
  const double octaves = std::log2(rate);
  const double per_entry = std::log2(kTempogramMaxBpm / kTempogramMinBpm) / (kNumTempogram - 1);
  const double shift = octaves / per_entry;
  std::array<double, kNumTempogram> in;
  for (int i = 0; i < kNumTempogram; ++i) in[i] = features[kTempogramBegin + i];
  for (int i = 0; i < kNumTempogram; ++i) {
    const double x = std::clamp(i + shift, 0.0, static_cast<double>(kNumTempogram - 1));
    const int a = std::min(static_cast<int>(std::floor(x)), kNumTempogram - 2);
    const double w = x - a;
    features[kTempogramBegin + i] = static_cast<float>(in[a] * (1.0 - w) + in[a + 1] * w);
  }
  features[kTempoIndex] = static_cast<float>(static_cast<double>(features[kTempoIndex]) - octaves);
}

void WarpedFeatureRow(const float* source, double rate, int64_t warped_frame, bool fold_tempo, double bar_frames,
                      float* out) {
  std::copy_n(source, kNumFeatures, out);
  if (fold_tempo) FoldTempoFeatures(rate, out);
  if (bar_frames > 0.0) BarClockPhase(warped_frame, bar_frames, out);
}

}  // namespace dance::engine::audio
