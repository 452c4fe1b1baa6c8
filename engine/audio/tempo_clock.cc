#include "engine/audio/tempo_clock.h"

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

}  // namespace dance::engine::audio
