// The recursive sliding DFT against a direct evaluation of the documented definition.
#include "engine/audio/incremental_pre.h"

#include <cmath>
#include <complex>
#include <random>
#include <vector>

#include "gtest/gtest.h"

namespace dance::engine::audio {
namespace {

// Direct evaluation of docs/features.md's PRE definition for frame n.
std::vector<float> DirectPre(const std::vector<std::array<float, kPreChannels>>& x, int64_t n) {
  std::vector<float> out(kPreDims);
  const double pi = 3.14159265358979323846;
  for (int c = 0; c < kPreChannels; ++c) {
    std::vector<std::complex<double>> d(kPreNumBins + 2);
    for (int k = 1; k < kPreNumBins + 2; ++k) {
      for (int m = 0; m < kPreWindow; ++m) {
        const int64_t i = n - kPreWindow + 1 + m;
        const double v = i >= 0 ? x[i][c] : 0.0;
        d[k] += v * std::polar(1.0, -2.0 * pi * k * m / kPreWindow);
      }
    }
    for (int b = 0; b < kPreNumBins; ++b) {
      const int k = b + 1;
      const std::complex<double> h = 0.5 * d[k] - 0.25 * (d[k - 1] + d[k + 1]);
      const double inv = 1.0 / std::sqrt(std::norm(h) + kPreEpsilon * kPreEpsilon);
      out[(c * kPreNumBins + b) * 2] = static_cast<float>(h.real() * inv);
      out[(c * kPreNumBins + b) * 2 + 1] = static_cast<float>(h.imag() * inv);
    }
  }
  return out;
}

TEST(IncrementalPre, MatchesDirectDftOverLongStreams) {
  std::mt19937 gen(5);
  std::normal_distribution<float> noise(0.0f, 1.0f);
  std::vector<std::array<float, kPreChannels>> x(5000);
  for (size_t n = 0; n < x.size(); ++n) {
    const double t = n / 30.0;
    x[n] = {static_cast<float>(std::fmax(0.0, std::sin(2 * 3.14159265 * 2.0 * t)) * 5 + noise(gen)),
            static_cast<float>(-3.0 + 0.5 * std::sin(t)), -6.0f, noise(gen) > 1.5f ? 3.0f : 0.0f};
  }
  IncrementalPre pre;
  std::vector<float> out(kPreDims);
  float worst = 0.0f;
  for (int64_t n = 0; n < static_cast<int64_t>(x.size()); ++n) {
    pre.Update(x[n], absl::MakeSpan(out));
    if (n < 200 || n % 97 == 0 || n > 4900) {
      const std::vector<float> direct = DirectPre(x, n);
      for (int i = 0; i < kPreDims; ++i) worst = std::max(worst, std::fabs(out[i] - direct[i]));
    }
  }
  EXPECT_LT(worst, 1e-5f);
}

TEST(IncrementalPre, OutputsAreBoundedAndConstantChannelsGiveZero) {
  IncrementalPre pre;
  std::vector<float> out(kPreDims);
  const std::array<float, kPreChannels> constant = {1.0f, -5.0f, -10.0f, 0.0f};
  for (int n = 0; n < 300; ++n) pre.Update(constant, absl::MakeSpan(out));
  // A constant window has no energy above DC (and D_0 is removed): outputs ~0.
  for (float v : out) EXPECT_LT(std::fabs(v), 1e-6f);
}

TEST(IncrementalPre, SnapshotRestore) {
  IncrementalPre a, b;
  std::vector<float> oa(kPreDims), ob(kPreDims);
  for (int n = 0; n < 150; ++n)
    a.Update({float(n % 7), float(n % 5), 0.0f, float(n % 3)}, absl::MakeSpan(oa));
  b.set_state(a.state());
  for (int n = 150; n < 300; ++n) {
    const std::array<float, kPreChannels> v = {float(n % 7), float(n % 5), 0.0f, float(n % 3)};
    a.Update(v, absl::MakeSpan(oa));
    b.Update(v, absl::MakeSpan(ob));
    ASSERT_EQ(oa, ob);
  }
}

}  // namespace
}  // namespace dance::engine::audio
