// TempoClock: octave folding, hysteresis, and the real <-> warped frame mapping (engine/audio/tempo_clock.h).
#include "engine/audio/tempo_clock.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include "gtest/gtest.h"

namespace dance::engine::audio {
namespace {

TEST(TempoClock, FoldsIntoTheReferenceOctave) {
  for (double tempo : {43.5, 87.0, 174.0, 348.0}) {
    TempoClock clock({.reference_bpm = 105.0});
    EXPECT_NEAR(clock.Fold(tempo), 87.0, 1e-9) << tempo;
  }
  TempoClock clock({.reference_bpm = 105.0});
  EXPECT_NEAR(clock.Fold(125.0), 125.0, 1e-9);
  TempoClock bad({.reference_bpm = 105.0});
  EXPECT_EQ(bad.Fold(std::nan("")), 105.0);
  EXPECT_EQ(bad.Fold(-3.0), 105.0);
}

TEST(TempoClock, KeepsItsOctaveNearTheEdge) {
  // Edge of the octave at 105 * sqrt 2 = 148.5 BPM: a tempo wobbling around it keeps the first choice.
  TempoClock clock({.reference_bpm = 105.0, .octave_hysteresis = 0.08});
  EXPECT_NEAR(clock.Fold(146.0), 146.0, 1e-9);
  EXPECT_NEAR(clock.Fold(152.0), 152.0, 1e-9);  // within 8 % above the edge: same octave
  EXPECT_NEAR(clock.Fold(170.0), 85.0, 1e-9);   // far beyond: the next octave
  EXPECT_NEAR(clock.Fold(140.0), 70.0, 1e-9);   // now 70 is within 8 % below 74.2: stays
  EXPECT_NEAR(clock.Fold(130.0), 130.0, 1e-9);  // 65 is too far below: back up
}

TEST(TempoClock, RateIsTempoOverReference) {
  TempoClock clock({.reference_bpm = 100.0});
  for (int n = 0; n < 300; ++n) {
    const TempoClock::Span s = clock.Push(125.0);
    EXPECT_DOUBLE_EQ(s.rate, 1.25);
    EXPECT_EQ(s.frame, n);
  }
  EXPECT_NEAR(clock.position(), 375.0, 1e-9);
  EXPECT_EQ(clock.warped_frames(), 375);
}

TEST(TempoClock, EveryWarpedFrameHasExactlyOneSourceInOrder) {
  TempoClock clock({.reference_bpm = 105.0});
  std::vector<int64_t> source;
  std::vector<double> position;
  for (int n = 0; n < 2000; ++n) {
    const double tempo = 80.0 + 60.0 * std::sin(n * 0.01);  // sweeps 80..140 BPM
    const TempoClock::Span s = clock.Push(tempo);
    EXPECT_EQ(s.first_warped, static_cast<int64_t>(source.size()));
    for (int64_t j = s.first_warped; j < s.end_warped; ++j) {
      // j lies in [W_n, W_{n+1}) and its real position in [n, n + 1).
      EXPECT_GE(static_cast<double>(j), s.begin);
      EXPECT_LT(static_cast<double>(j), s.end);
      const double x = s.RealPosition(j);
      EXPECT_GE(x, static_cast<double>(n));
      EXPECT_LT(x, n + 1.0);
      if (!position.empty()) {
        EXPECT_GT(x, position.back());
      }
      source.push_back(n);
      position.push_back(x);
    }
  }
  EXPECT_EQ(static_cast<int64_t>(source.size()), clock.warped_frames());
  EXPECT_EQ(clock.warped_frames(), static_cast<int64_t>(std::ceil(clock.position())));
}

TEST(TempoClock, CopyContinuesIdentically) {
  TempoClock a({.reference_bpm = 105.0});
  for (int n = 0; n < 100; ++n) a.Push(90.0 + n * 0.5);
  TempoClock b = a;
  for (int n = 0; n < 100; ++n) {
    const TempoClock::Span sa = a.Push(150.0 - n), sb = b.Push(150.0 - n);
    EXPECT_EQ(sa.begin, sb.begin);
    EXPECT_EQ(sa.end_warped, sb.end_warped);
  }
}

TEST(BarClock, IsAMetronomeOfBeatsPerBarAtTheReference) {
  // 3 beats at 86 BPM = 3 * 1800 / 86 warped frames.
  const double bar = BarClockFrames(3, 86.0);
  EXPECT_NEAR(bar, 5400.0 / 86.0, 1e-12);
  std::vector<float> row(kNumFeatures, 7.0f);
  auto phase = [&](int64_t j) {
    BarClockPhase(j, bar, row.data());
    return std::atan2(row[kBarPhaseSinIndex], row[kBarPhaseCosIndex]);
  };
  EXPECT_NEAR(phase(0), 0.0, 1e-7);
  EXPECT_FLOAT_EQ(row[kBarPhaseCosIndex], 1.0f);
  // Any frame: the formula.
  for (int64_t j : {10, 100, 1000, 123456}) {
    const double x = j / bar - std::floor(j / bar);
    const double expected = 2.0 * M_PI * x;
    EXPECT_NEAR(std::remainder(phase(j) - expected, 2.0 * M_PI), 0.0, 1e-6) << j;
  }
  // Periodic in the bar: frames a whole number of bars apart (4 bars at 90 BPM x 4 beats = 320 frames).
  const double bar4 = BarClockFrames(4, 90.0);  // 80 frames
  BarClockPhase(7, bar4, row.data());
  const float c = row[kBarPhaseCosIndex], s = row[kBarPhaseSinIndex];
  BarClockPhase(7 + 320, bar4, row.data());
  EXPECT_NEAR(row[kBarPhaseCosIndex], c, 1e-6);
  EXPECT_NEAR(row[kBarPhaseSinIndex], s, 1e-6);
  // Only the two bar_phase entries are written.
  for (int i = 0; i < kNumFeatures; ++i) {
    if (i != kBarPhaseCosIndex && i != kBarPhaseSinIndex) {
      EXPECT_EQ(row[i], 7.0f) << i;
    }
  }
}

TEST(FoldTempo, ShowsTheSongAtTheFoldedReference) {
  // A song tracked at 115 BPM on a clock at reference 125 (rate 0.92): after the fold its tempo feature
  // and its tempogram's peak are at 125 BPM; every other entry is the same.
  const double per_entry = std::log2(kTempogramMaxBpm / kTempogramMinBpm) / (kNumTempogram - 1);
  auto index_of = [&](double bpm) { return std::log2(bpm / kTempogramMinBpm) / per_entry; };
  std::vector<float> row(kNumFeatures, 3.0f);
  row[kTempoIndex] = static_cast<float>(std::log2(115.0 / 120.0));
  for (int i = 0; i < kNumTempogram; ++i) {
    row[kTempogramBegin + i] = static_cast<float>(std::exp(-0.5 * std::pow((i - index_of(115.0)) / 2.0, 2)));
  }
  std::vector<float> folded = row;
  FoldTempoFeatures(115.0 / 125.0, folded.data());
  EXPECT_NEAR(120.0 * std::exp2(folded[kTempoIndex]), 125.0, 1e-4);
  int peak = 0;
  for (int i = 1; i < kNumTempogram; ++i) {
    if (folded[kTempogramBegin + i] > folded[kTempogramBegin + peak]) peak = i;
  }
  // Parabolic refinement of the peak's position.
  const double ym = folded[kTempogramBegin + peak - 1], y0 = folded[kTempogramBegin + peak],
               yp = folded[kTempogramBegin + peak + 1];
  const double at = peak + 0.5 * (ym - yp) / (ym - 2.0 * y0 + yp);
  EXPECT_NEAR(at, index_of(125.0), 0.1);
  EXPECT_GT(index_of(125.0) - index_of(115.0), 2.5);  // (the shift is real: 2.8 entries)
  for (int i = 0; i < kNumFeatures; ++i) {
    if (i != kTempoIndex && (i < kTempogramBegin || i >= kTempogramBegin + kNumTempogram)) {
      EXPECT_EQ(folded[i], 3.0f) << i;
    }
  }
}

TEST(FoldTempo, InterpolatesLinearlyAndClampsAtTheEnds) {
  const double per_entry = std::log2(kTempogramMaxBpm / kTempogramMinBpm) / (kNumTempogram - 1);
  std::vector<float> row(kNumFeatures, 0.0f);
  for (int i = 0; i < kNumTempogram; ++i) row[kTempogramBegin + i] = 0.5f + 0.01f * i;  // linear in the index
  for (double rate : {0.75, 0.92, 1.0, 1.1, 1.35}) {
    std::vector<float> f = row;
    FoldTempoFeatures(rate, f.data());
    const double shift = std::log2(rate) / per_entry;  // entry i takes the value at i + shift
    for (int i = 0; i < kNumTempogram; ++i) {
      const double x = std::clamp(i + shift, 0.0, kNumTempogram - 1.0);
      EXPECT_NEAR(f[kTempogramBegin + i], 0.5 + 0.01 * x, 1e-6) << "rate " << rate << " entry " << i;
    }
    EXPECT_NEAR(f[kTempoIndex], -std::log2(rate), 1e-6);
  }
  // Rate 1 changes nothing; a rate that is not a positive number is ignored.
  for (double rate : {1.0, 0.0, -1.0, std::nan("")}) {
    std::vector<float> f = row;
    FoldTempoFeatures(rate, f.data());
    EXPECT_EQ(f, row) << rate;
  }
}

}  // namespace
}  // namespace dance::engine::audio
