// Synthetic signals and a whole-stream runner shared by the audio tests.
#ifndef DANCE_TESTS_ENGINE_AUDIO_TEST_SIGNALS_H_
#define DANCE_TESTS_ENGINE_AUDIO_TEST_SIGNALS_H_

#include <cmath>
#include <cstdint>
#include <random>
#include <vector>

#include "absl/types/span.h"
#include "engine/audio/audio_front_end.h"
#include "gtest/gtest.h"

namespace dance::engine::audio::testing {

inline constexpr double kTestPi = 3.14159265358979323846;

// Mono click track: a 1 kHz decaying 10 ms blip at t0 + k * 60 / bpm seconds.
inline std::vector<float> ClickTrack(double bpm, double seconds, int rate, double t0,
                                     std::vector<double>* click_times = nullptr) {
  std::vector<float> x(static_cast<size_t>(seconds * rate), 0.0f);
  const int len = rate / 100;
  for (double t = t0; t < seconds; t += 60.0 / bpm) {
    if (click_times) click_times->push_back(t);
    const size_t start = static_cast<size_t>(std::llround(t * rate));
    for (int i = 0; i < len && start + i < x.size(); ++i) {
      x[start + i] += static_cast<float>(0.5 * std::sin(2.0 * kTestPi * 1000.0 * i / rate) *
                                         std::exp(-i / (0.002 * rate)));
    }
  }
  return x;
}

// Music-like test signal: chords, noise bursts and a kick, seeded; interleaved with `channels`.
inline std::vector<float> TestMusic(double seconds, int rate, int channels, uint32_t seed) {
  std::mt19937 gen(seed);
  std::normal_distribution<float> noise(0.0f, 1.0f);
  const size_t n = static_cast<size_t>(seconds * rate);
  std::vector<float> x(n * channels);
  for (size_t i = 0; i < n; ++i) {
    const double t = static_cast<double>(i) / rate;
    const double beat = std::fmod(t, 0.5);
    double v = 0.2 * std::sin(2 * kTestPi * 220.0 * t) + 0.1 * std::sin(2 * kTestPi * 277.2 * t) +
               0.4 * std::exp(-beat * 30.0) * std::sin(2 * kTestPi * 60.0 * t);
    v += 0.05 * noise(gen) * std::exp(-std::fmod(t + 0.25, 0.5) * 40.0);
    for (int c = 0; c < channels; ++c)
      x[i * channels + c] = static_cast<float>(v * (1.0 - 0.2 * c));
  }
  return x;
}

// Feeds `interleaved` in the given chunk sizes (in frames, cycled), flushes, returns all frames.
inline FeatureFrames RunStream(const AudioFrontEndOptions& options,
                               absl::Span<const float> interleaved,
                               const std::vector<int64_t>& chunk_frames) {
  auto fe = AudioFrontEnd::Create(options);
  EXPECT_TRUE(fe.ok()) << fe.status();
  FeatureFrames all, part;
  const int64_t total = static_cast<int64_t>(interleaved.size()) / options.channels;
  size_t ci = 0;
  for (int64_t start = 0; start < total;) {
    const int64_t n = std::min(chunk_frames[ci++ % chunk_frames.size()], total - start);
    EXPECT_TRUE(
        (*fe)->PushFloat(interleaved.subspan(start * options.channels, n * options.channels)).ok());
    start += n;
    (*fe)->PopFrames(&part);
    all.features.insert(all.features.end(), part.features.begin(), part.features.end());
    all.pre.insert(all.pre.end(), part.pre.begin(), part.pre.end());
    all.pre_input.insert(all.pre_input.end(), part.pre_input.begin(), part.pre_input.end());
    all.beat_times_s.insert(all.beat_times_s.end(), part.beat_times_s.begin(),
                            part.beat_times_s.end());
  }
  EXPECT_TRUE((*fe)->Flush().ok());
  (*fe)->PopFrames(&part);
  all.features.insert(all.features.end(), part.features.begin(), part.features.end());
  all.pre.insert(all.pre.end(), part.pre.begin(), part.pre.end());
  all.pre_input.insert(all.pre_input.end(), part.pre_input.begin(), part.pre_input.end());
  all.beat_times_s.insert(all.beat_times_s.end(), part.beat_times_s.begin(),
                          part.beat_times_s.end());
  return all;
}

inline float MaxAbsDiff(const std::vector<float>& a, const std::vector<float>& b, size_t count) {
  float m = 0.0f;
  for (size_t i = 0; i < count; ++i) m = std::max(m, std::fabs(a[i] - b[i]));
  return m;
}

}  // namespace dance::engine::audio::testing

#endif  // DANCE_TESTS_ENGINE_AUDIO_TEST_SIGNALS_H_
