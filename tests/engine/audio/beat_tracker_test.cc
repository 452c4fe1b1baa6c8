// Tempo and beats on synthetic click tracks: tempo within 2 %, beats within one frame.
#include <cmath>
#include <vector>

#include "engine/audio/audio_front_end.h"
#include "engine/audio/feature_layout.h"
#include "gtest/gtest.h"
#include "tests/engine/audio/test_signals.h"

namespace dance::engine::audio {
namespace {

struct ClickCase {
  double bpm;
  int rate;
};

class ClickTrackTest : public ::testing::TestWithParam<ClickCase> {};

TEST_P(ClickTrackTest, TempoAndBeats) {
  const ClickCase c = GetParam();
  std::vector<double> clicks;
  const std::vector<float> audio = testing::ClickTrack(c.bpm, 30.0, c.rate, 0.37, &clicks);
  const FeatureFrames frames = testing::RunStream({c.rate, 1}, audio, {4321});
  ASSERT_EQ(frames.frames(), 900);
  // Running tempo from 8 s on (one tempogram window) within 2 %.
  for (int64_t n = 240; n < frames.frames(); n += 30) {
    const double bpm = 120.0 * std::exp2(frames.features[n * kNumFeatures + kTempoIndex]);
    ASSERT_NEAR(bpm, c.bpm, 0.02 * c.bpm) << "frame " << n;
  }
  // Beats after 8 s: one per click, each within one frame (1/30 s) of its click.
  int matched = 0, beats = 0;
  for (double b : frames.beat_times_s) {
    if (b < 8.0) continue;
    ++beats;
    double best = 1e9;
    for (double t : clicks) best = std::min(best, std::fabs(b - t));
    EXPECT_LT(best, 1.0 / kFrameRate) << "beat at " << b << " s";
    matched += best < 1.0 / kFrameRate;
  }
  int expected = 0;
  for (double t : clicks) expected += t >= 8.0 + 1.0 / kFrameRate && t < 30.0 - 1.0 / kFrameRate;
  EXPECT_GE(beats, expected);
  EXPECT_LE(beats, expected + 2);
  EXPECT_GE(matched, expected);
  // The beat phase feature follows the clicks: at each frame end T, phase = (T - last click) /
  // period.
  double abs_err_sum = 0.0;
  int count = 0;
  const double period = 60.0 / c.bpm;
  for (int64_t n = 240; n < frames.frames(); ++n) {
    const double t_end = (n + 1) / kFrameRate;
    const double want = std::fmod(t_end - clicks[0], period) / period;
    const double actual = std::atan2(frames.features[n * kNumFeatures + kBeatPhaseSinIndex],
                                     frames.features[n * kNumFeatures + kBeatPhaseCosIndex]) /
                          (2.0 * testing::kTestPi);
    double err = actual - want;
    err -= std::round(err);
    abs_err_sum += std::fabs(err);
    ++count;
  }
  EXPECT_LT(abs_err_sum / count, 0.05) << "mean beat-phase error in beats";
}

INSTANTIATE_TEST_SUITE_P(Tempi, ClickTrackTest,
                         ::testing::Values(ClickCase{60, 24000}, ClickCase{90, 24000},
                                           ClickCase{120, 24000}, ClickCase{150, 24000},
                                           ClickCase{180, 24000}, ClickCase{97, 44100},
                                           ClickCase{133, 16000}));

TEST(BeatTracker, TempogramPeaksAtTheClickPeriod) {
  const std::vector<float> audio = testing::ClickTrack(120.0, 12.0, 24000, 0.1);
  const FeatureFrames frames = testing::RunStream({24000, 1}, audio, {24000});
  const int64_t n = frames.frames() - 1;
  const float* tg = frames.features.data() + n * kNumFeatures + kTempogramBegin;
  int best = 0;
  for (int i = 0; i < kNumTempogram; ++i) best = tg[i] > tg[best] ? i : best;
  const double ratio = std::pow(kTempogramMaxBpm / kTempogramMinBpm, 1.0 / (kNumTempogram - 1));
  const double bpm = kTempogramMinBpm * std::pow(ratio, best);
  // The autocorrelation is high at 120 BPM and its sub-multiple 60 BPM; 120 must be among the
  // peaks.
  const int i120 =
      static_cast<int>(std::lround(std::log(120.0 / kTempogramMinBpm) / std::log(ratio)));
  EXPECT_GT(tg[i120], 0.5f) << "peak at " << bpm;
  const int i90 =
      static_cast<int>(std::lround(std::log(90.0 / kTempogramMinBpm) / std::log(ratio)));
  EXPECT_LT(tg[i90], 0.2f);
}

}  // namespace
}  // namespace dance::engine::audio
