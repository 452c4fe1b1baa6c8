// Incremental PRE (phase-based rhythm extraction): per frame, the phases of a Hann-windowed DFT
// over the last kPreWindow frames of kPreChannels rhythm channels, bins 1..16, as (cos, sin).
//
// Definition (the batch reference training/experiments/pre_reference.py computes the same numbers):
//   x_c(n)   channel c at frame n; x_c(n) = 0 for n < 0
//   D_k(n)   = sum_{m=0}^{N-1} x(n-N+1+m) exp(-i 2 pi k m / N)       (N = 64, oldest frame at m =
//   0) H_k(n)   = 0.5 D_k - 0.25 D_{k-1} - 0.25 D_{k+1}, with D_0 := 0    (periodic Hann; the
//   window's mean
//              is removed, so a channel's DC level does not leak into bin 1)
//   out      = (Re H_k, Im H_k) / sqrt(|H_k|^2 + eps^2), eps = kPreEpsilon (continuous as |H| -> 0)
// Layout of the 128 outputs: index = (c * 16 + (k - 1)) * 2 + {0: cos, 1: sin}.
// Update: the recursive sliding DFT D_k(n) = exp(i 2 pi k / N) (D_k(n-1) - x(n-N) + x(n)) in double
// precision, O(channels x bins) per frame; every N frames D is recomputed exactly from the ring
// buffer so rounding cannot accumulate over hours of audio. Not thread-safe; no allocation; state
// is a copyable struct.
#ifndef DANCE_ENGINE_AUDIO_INCREMENTAL_PRE_H_
#define DANCE_ENGINE_AUDIO_INCREMENTAL_PRE_H_

#include <array>
#include <complex>
#include <cstdint>

#include "absl/types/span.h"
#include "engine/audio/feature_layout.h"

namespace dance::engine::audio {

struct IncrementalPreState {
  // Ring of the last kPreWindow inputs per channel, indexed by frame % kPreWindow.
  std::array<std::array<double, kPreWindow>, kPreChannels> ring{};
  // D_k for k = 0..kPreNumBins + 1 per channel.
  std::array<std::array<std::complex<double>, kPreNumBins + 2>, kPreChannels> dft{};
  int64_t frames = 0;
};

class IncrementalPre {
 public:
  IncrementalPre();
  // Consumes one frame of channel values (size kPreChannels) and writes kPreDims outputs.
  void Update(absl::Span<const float> channels, absl::Span<float> out);
  void Reset() { state_ = IncrementalPreState{}; }
  const IncrementalPreState& state() const { return state_; }
  void set_state(const IncrementalPreState& state) { state_ = state; }

 private:
  void Recompute();
  IncrementalPreState state_;
  std::array<std::complex<double>, kPreNumBins + 2> twiddle_;  // exp(i 2 pi k / N)
  std::array<std::complex<double>, kPreWindow> roots_;         // exp(-i 2 pi j / N)
};

}  // namespace dance::engine::audio

#endif  // DANCE_ENGINE_AUDIO_INCREMENTAL_PRE_H_
