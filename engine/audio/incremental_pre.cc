#include "engine/audio/incremental_pre.h"

#include <cmath>

#include "absl/base/internal/raw_logging.h"

namespace dance::engine::audio {
namespace {
constexpr double kPi = 3.14159265358979323846;
constexpr int kNumDft = kPreNumBins + 2;  // D_0 .. D_17
}  // namespace

IncrementalPre::IncrementalPre() {
  for (int k = 0; k < kNumDft; ++k) twiddle_[k] = std::polar(1.0, 2.0 * kPi * k / kPreWindow);
  for (int j = 0; j < kPreWindow; ++j) roots_[j] = std::polar(1.0, -2.0 * kPi * j / kPreWindow);
}

void IncrementalPre::Recompute() {
  // Exact DFT of the window ending at frame state_.frames - 1 (oldest first).
  for (int c = 0; c < kPreChannels; ++c) {
    for (int k = 0; k < kNumDft; ++k) {
      std::complex<double> acc = 0.0;
      for (int m = 0; m < kPreWindow; ++m) {
        const int64_t n = state_.frames - kPreWindow + m;
        const double x = n >= 0 ? state_.ring[c][n % kPreWindow] : 0.0;
        acc += x * roots_[(k * m) % kPreWindow];
      }
      state_.dft[c][k] = acc;
    }
  }
}

void IncrementalPre::Update(absl::Span<const float> channels, absl::Span<float> out) {
  ABSL_RAW_CHECK(channels.size() == kPreChannels && out.size() == kPreDims,
                 "IncrementalPre: bad span sizes");
  const int slot = static_cast<int>(state_.frames % kPreWindow);
  for (int c = 0; c < kPreChannels; ++c) {
    const double oldest = state_.frames >= kPreWindow ? state_.ring[c][slot] : 0.0;
    const double x = channels[c];
    state_.ring[c][slot] = x;
    for (int k = 0; k < kNumDft; ++k)
      state_.dft[c][k] = twiddle_[k] * (state_.dft[c][k] - oldest + x);
  }
  ++state_.frames;
  if (state_.frames % kPreWindow == 0) Recompute();

  constexpr double kEps2 = kPreEpsilon * kPreEpsilon;
  for (int c = 0; c < kPreChannels; ++c) {
    const auto& d = state_.dft[c];
    for (int b = 0; b < kPreNumBins; ++b) {
      const int k = kPreFirstBin + b;
      const std::complex<double> lower = k - 1 == 0 ? 0.0 : d[k - 1];
      const std::complex<double> h = 0.5 * d[k] - 0.25 * (lower + d[k + 1]);
      const double inv = 1.0 / std::sqrt(std::norm(h) + kEps2);
      out[(c * kPreNumBins + b) * 2] = static_cast<float>(h.real() * inv);
      out[(c * kPreNumBins + b) * 2 + 1] = static_cast<float>(h.imag() * inv);
    }
  }
}

}  // namespace dance::engine::audio
