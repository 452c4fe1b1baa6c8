// Spectral front end: mel scale, sine levels, chroma of a steady tone.
#include "engine/audio/spectral.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include "gtest/gtest.h"

namespace dance::engine::audio {
namespace {

std::vector<float> Sine(double hz, double amplitude) {
  std::vector<float> w(kWindowSamples);
  for (int i = 0; i < kWindowSamples; ++i) {
    w[i] = static_cast<float>(amplitude * std::sin(2 * 3.14159265358979 * hz * i / kSampleRate));
  }
  return w;
}

TEST(Spectral, MelScaleRoundTripsAndIsSlaney) {
  for (double hz : {0.0, 100.0, 999.0, 1000.0, 4000.0, 12000.0})
    EXPECT_NEAR(MelToHz(HzToMel(hz)), hz, 1e-6);
  EXPECT_NEAR(HzToMel(1000.0), 15.0, 1e-9);
  EXPECT_NEAR(HzToMel(6400.0), 42.0, 1e-9);
}

TEST(Spectral, FullScaleSineRmsAndChroma) {
  SpectralAnalyzer analyzer;
  SpectralFrame frame;
  const std::vector<float> a4 = Sine(440.0, 1.0);
  analyzer.Analyze(a4.data(), &frame);
  EXPECT_NEAR(frame.rms_db, -3.01, 0.05);  // RMS of a unit sine
  int best = 0;
  for (int c = 0; c < kNumChroma; ++c) best = frame.chroma[c] > frame.chroma[best] ? c : best;
  EXPECT_EQ(best, 9);  // A
  EXPECT_FLOAT_EQ(frame.chroma[9], 1.0f);
  EXPECT_LT(frame.chroma[3], 0.05f);  // D#, a tritone away
  // The mel band holding 440 Hz is the loudest and near 0 dB re full scale (minus the band's
  // spread).
  int loud = 0;
  for (int b = 0; b < kNumMelBands; ++b)
    loud = frame.log_mel_db[b] > frame.log_mel_db[loud] ? b : loud;
  const double lo =
      MelToHz(HzToMel(0.0) + (HzToMel(12000.0) - HzToMel(0.0)) * loud / (kNumMelBands + 1));
  const double hi =
      MelToHz(HzToMel(0.0) + (HzToMel(12000.0) - HzToMel(0.0)) * (loud + 2) / (kNumMelBands + 1));
  EXPECT_LT(lo, 440.0);
  EXPECT_GT(hi, 440.0);
}

TEST(Spectral, LevelsScaleInDecibels) {
  SpectralAnalyzer analyzer;
  SpectralFrame loud, quiet;
  const std::vector<float> sine_a = Sine(1000.0, 0.5), sine_b = Sine(1000.0, 0.05);
  analyzer.Analyze(sine_a.data(), &loud);
  analyzer.Analyze(sine_b.data(), &quiet);
  EXPECT_NEAR(loud.rms_db - quiet.rms_db, 20.0, 0.01);
  float loud_max = -200.0f, quiet_max = -200.0f;
  for (int b = 0; b < kNumMelBands; ++b) {
    loud_max = std::max(loud_max, loud.log_mel_db[b]);
    quiet_max = std::max(quiet_max, quiet.log_mel_db[b]);
  }
  EXPECT_NEAR(loud_max - quiet_max, 20.0, 0.01);
}

TEST(Spectral, SilenceIsFloored) {
  SpectralAnalyzer analyzer;
  SpectralFrame frame;
  const std::vector<float> zeros(kWindowSamples, 0.0f);
  analyzer.Analyze(zeros.data(), &frame);
  EXPECT_FLOAT_EQ(frame.rms_db, -100.0f);
  for (float v : frame.log_mel_db) EXPECT_FLOAT_EQ(v, -100.0f);
  for (float v : frame.chroma) EXPECT_EQ(v, 0.0f);
  EXPECT_NEAR(frame.mfcc[0], -800.0f, 1e-3);
}

}  // namespace
}  // namespace dance::engine::audio
