// Properties of the streaming front end: chunking invariance, causality, snapshot/restore, bad
// input.
#include "engine/audio/audio_front_end.h"

#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include "gtest/gtest.h"
#include "tests/engine/audio/test_signals.h"

namespace dance::engine::audio {
namespace {

using testing::MaxAbsDiff;
using testing::RunStream;
using testing::TestMusic;

std::vector<int64_t> RandomChunks(uint32_t seed, int rate) {
  std::mt19937 gen(seed);
  // Log-uniform sizes from 1 sample to 1 s.
  std::uniform_real_distribution<double> u(0.0, std::log(static_cast<double>(rate)));
  std::vector<int64_t> chunks(997);
  for (auto& c : chunks) c = std::max<int64_t>(1, static_cast<int64_t>(std::exp(u(gen))));
  return chunks;
}

class ChunkingTest : public ::testing::TestWithParam<std::pair<int, int>> {};

TEST_P(ChunkingTest, RandomChunkingsGiveIdenticalFrames) {
  const auto [rate, channels] = GetParam();
  AudioFrontEndOptions options{rate, channels};
  const std::vector<float> audio = TestMusic(6.0, rate, channels, 7);
  const FeatureFrames reference = RunStream(options, audio, {static_cast<int64_t>(rate)});
  ASSERT_GT(reference.frames(), 170);
  for (uint32_t seed = 1; seed <= 4; ++seed) {
    const FeatureFrames other = RunStream(options, audio, RandomChunks(seed, rate));
    ASSERT_EQ(other.frames(), reference.frames()) << "seed " << seed;
    EXPECT_LE(MaxAbsDiff(other.features, reference.features, reference.features.size()), 1e-6f)
        << seed;
    EXPECT_LE(MaxAbsDiff(other.pre, reference.pre, reference.pre.size()), 1e-6f) << seed;
    EXPECT_EQ(other.beat_times_s, reference.beat_times_s);
  }
  // One sample at a time, the extreme case.
  const FeatureFrames single = RunStream(options, audio, {1});
  EXPECT_LE(MaxAbsDiff(single.features, reference.features, reference.features.size()), 1e-6f);
}

INSTANTIATE_TEST_SUITE_P(Rates, ChunkingTest,
                         ::testing::Values(std::pair{24000, 1}, std::pair{44100, 2},
                                           std::pair{8000, 1}, std::pair{96000, 3}));

class CausalityTest : public ::testing::TestWithParam<int> {};

TEST_P(CausalityTest, FutureAudioDoesNotChangePastFrames) {
  const int rate = GetParam();
  AudioFrontEndOptions options{rate, 1};
  std::vector<float> audio = TestMusic(5.0, rate, 1, 3);
  const FeatureFrames reference = RunStream(options, audio, {4096});
  // Perturb everything from time x on (x = 2.5 s on the input timeline).
  const size_t x = static_cast<size_t>(2.5 * rate);
  std::mt19937 gen(11);
  std::uniform_real_distribution<float> u(-0.8f, 0.8f);
  for (size_t i = x; i < audio.size(); ++i) audio[i] = u(gen);
  const FeatureFrames perturbed = RunStream(options, audio, {4096});
  ASSERT_EQ(perturbed.frames(), reference.frames());
  // Frame n ends at 24 kHz sample (n + 1) * 800, i.e. time (n + 1) / 30 s; lookahead is 0.
  const int64_t last_unaffected = static_cast<int64_t>(std::floor(2.5 * kFrameRate)) - 1;
  const size_t count = static_cast<size_t>(last_unaffected + 1);
  // At 24 kHz nothing is filtered: exact. Resampled input carries soxr's FFT round-off (its blocks
  // straddle x), far below any audible or model-relevant level.
  const float tolerance = rate == kSampleRate ? 0.0f : 1e-3f;
  EXPECT_LE(MaxAbsDiff(perturbed.features, reference.features, count * kNumFeatures), tolerance);
  EXPECT_LE(MaxAbsDiff(perturbed.pre, reference.pre, count * kPreDims), tolerance);
  // And the perturbation is visible right after x (the test can fail).
  const size_t next = count + 1;
  EXPECT_GT(MaxAbsDiff(perturbed.features, reference.features, next * kNumFeatures), 0.0f);
}

INSTANTIATE_TEST_SUITE_P(Rates, CausalityTest, ::testing::Values(24000, 44100, 16000));

TEST(AudioFrontEnd, SnapshotRestoreContinuesIdentically) {
  for (int rate : {24000, 44100}) {
    AudioFrontEndOptions options{rate, 2};
    const std::vector<float> audio = TestMusic(6.0, rate, 2, 5);
    const FeatureFrames reference = RunStream(options, audio, {1000});
    auto fe = *AudioFrontEnd::Create(options);
    const size_t half = static_cast<size_t>(3.0 * rate) * 2 + 2 * 333;
    ASSERT_TRUE(fe->PushFloat(absl::MakeConstSpan(audio).subspan(0, half)).ok());
    const AudioFrontEndSnapshot snap = fe->Snapshot();
    // Diverge, then restore into a fresh instance and into the diverged one.
    ASSERT_TRUE(fe->PushFloat(std::vector<float>(48000, 0.3f)).ok());
    auto fresh = *AudioFrontEnd::Create(options);
    // Exact at 24 kHz; resampled streams differ by soxr's FFT round-off after a restore (see
    // resampler.h).
    const float tolerance = rate == kSampleRate ? 0.0f : 1e-3f;
    for (AudioFrontEnd* target : {fe.get(), fresh.get()}) {
      ASSERT_TRUE(target->Restore(snap).ok());
      ASSERT_TRUE(target->PushFloat(absl::MakeConstSpan(audio).subspan(half)).ok());
      ASSERT_TRUE(target->Flush().ok());
      FeatureFrames frames;
      target->PopFrames(&frames);
      ASSERT_EQ(frames.frames(), reference.frames()) << rate;
      EXPECT_LE(MaxAbsDiff(frames.features, reference.features, reference.features.size()),
                tolerance)
          << rate;
      EXPECT_LE(MaxAbsDiff(frames.pre, reference.pre, reference.pre.size()), tolerance) << rate;
    }
  }
}

TEST(AudioFrontEnd, ResetStartsOver) {
  AudioFrontEndOptions options{22050, 1};
  const std::vector<float> audio = TestMusic(2.0, 22050, 1, 9);
  auto fe = *AudioFrontEnd::Create(options);
  FeatureFrames first, second;
  ASSERT_TRUE(fe->PushFloat(audio).ok());
  ASSERT_TRUE(fe->Flush().ok());
  fe->PopFrames(&first);
  EXPECT_FALSE(fe->PushFloat(audio).ok());  // after Flush
  fe->Reset();
  ASSERT_TRUE(fe->PushFloat(audio).ok());
  ASSERT_TRUE(fe->Flush().ok());
  fe->PopFrames(&second);
  EXPECT_EQ(second.first_index, 0);
  EXPECT_EQ(first.features, second.features);
}

TEST(AudioFrontEnd, RejectsBadRatesAndChannels) {
  for (int rate : {0, -1, 7999, 96001, 10'000'000}) {
    auto fe = AudioFrontEnd::Create({rate, 1});
    EXPECT_EQ(fe.status().code(), absl::StatusCode::kInvalidArgument) << rate;
    EXPECT_NE(fe.status().message().find("sample rate"), std::string::npos);
  }
  for (int channels : {0, -2, 9, 100}) {
    auto fe = AudioFrontEnd::Create({24000, channels});
    EXPECT_EQ(fe.status().code(), absl::StatusCode::kInvalidArgument) << channels;
    EXPECT_NE(fe.status().message().find("channel"), std::string::npos);
  }
}

TEST(AudioFrontEnd, RejectsPartialMultichannelFrame) {
  auto fe = *AudioFrontEnd::Create({24000, 2});
  EXPECT_EQ(fe->PushFloat(std::vector<float>(3, 0.0f)).code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(fe->PushInt16(std::vector<int16_t>(5, 0)).code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(fe->input_frames(), 0);
}

TEST(AudioFrontEnd, NonFiniteSamplesAreSanitisedToZero) {
  std::vector<float> audio = TestMusic(3.0, 24000, 1, 2);
  std::vector<float> zeroed = audio;
  for (size_t i = 1000; i < audio.size(); i += 997) {
    audio[i] = (i / 997) % 3 == 0   ? std::numeric_limits<float>::quiet_NaN()
               : (i / 997) % 3 == 1 ? std::numeric_limits<float>::infinity()
                                    : -std::numeric_limits<float>::infinity();
    zeroed[i] = 0.0f;
  }
  auto fe = *AudioFrontEnd::Create({24000, 1});
  ASSERT_TRUE(fe->PushFloat(audio).ok());
  EXPECT_GT(fe->sanitized_samples(), 60);
  FeatureFrames dirty;
  fe->PopFrames(&dirty);
  for (float v : dirty.features) ASSERT_TRUE(std::isfinite(v));
  for (float v : dirty.pre) ASSERT_TRUE(std::isfinite(v));
  const FeatureFrames clean = RunStream({24000, 1}, zeroed, {24000});
  EXPECT_EQ(MaxAbsDiff(dirty.features, clean.features, dirty.features.size()), 0.0f);
}

TEST(AudioFrontEnd, HugeSamplesStayFinite) {
  std::vector<float> audio(48000, 3e38f);
  for (size_t i = 0; i < audio.size(); i += 2) audio[i] = -3e38f;
  const FeatureFrames frames = RunStream({24000, 1}, audio, {4800});
  ASSERT_GT(frames.frames(), 50);
  for (float v : frames.features) ASSERT_TRUE(std::isfinite(v));
}

TEST(AudioFrontEnd, SilenceGivesFiniteFeatures) {
  for (int rate : {24000, 48000}) {
    const FeatureFrames frames =
        RunStream({rate, 2}, std::vector<float>(rate * 2 * 4, 0.0f), {rate});
    ASSERT_EQ(frames.frames(), 120) << rate;
    for (float v : frames.features) ASSERT_TRUE(std::isfinite(v));
    for (float v : frames.pre) ASSERT_TRUE(std::isfinite(v));
    EXPECT_FLOAT_EQ(frames.features[kRmsDbIndex], -100.0f);
    EXPECT_FLOAT_EQ(frames.features[kOnsetIndex], 0.0f);
    EXPECT_TRUE(frames.beat_times_s.empty() || frames.features[kBeatConfidenceIndex] == 0.0f);
  }
}

TEST(AudioFrontEnd, Int16MatchesScaledFloat) {
  const std::vector<float> music = TestMusic(2.0, 16000, 2, 4);
  std::vector<int16_t> pcm(music.size());
  std::vector<float> scaled(music.size());
  for (size_t i = 0; i < music.size(); ++i) {
    pcm[i] = static_cast<int16_t>(std::lround(std::clamp(music[i], -1.0f, 1.0f) * 32767.0f));
    scaled[i] = pcm[i] / 32768.0f;
  }
  auto a = *AudioFrontEnd::Create({16000, 2});
  ASSERT_TRUE(a->PushInt16(pcm).ok());
  FeatureFrames fa;
  a->PopFrames(&fa);
  const FeatureFrames fb = RunStream({16000, 2}, scaled, {16000});
  ASSERT_GT(fa.frames(), 0);
  EXPECT_LE(MaxAbsDiff(fa.features, fb.features, fa.features.size()), 1e-6f);
}

TEST(AudioFrontEnd, PopFramesInPieces) {
  const std::vector<float> audio = TestMusic(3.0, 24000, 1, 8);
  auto fe = *AudioFrontEnd::Create({24000, 1});
  ASSERT_TRUE(fe->PushFloat(audio).ok());
  const int64_t total = fe->FramesReady();
  ASSERT_EQ(total, 90);
  FeatureFrames a, b;
  fe->PopFrames(&a, 40);
  fe->PopFrames(&b);
  EXPECT_EQ(a.frames(), 40);
  EXPECT_EQ(a.first_index, 0);
  EXPECT_EQ(b.first_index, 40);
  EXPECT_EQ(b.frames(), 50);
  EXPECT_EQ(fe->FramesReady(), 0);
}

}  // namespace
}  // namespace dance::engine::audio
