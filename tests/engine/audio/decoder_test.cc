// Decoding real formats (written here with libsndfile) and bad input.
#include "engine/audio/decoder.h"

#include <sndfile.h>

#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <string>
#include <vector>

#include "gtest/gtest.h"

namespace dance::engine::audio {
namespace {

std::string TempPath(const std::string& name) { return ::testing::TempDir() + "/" + name; }

// Writes `frames` frames of a 440 Hz tone with libsndfile; returns false if the format is
// unsupported.
bool WriteTone(const std::string& path, int format, int rate, int channels, int frames) {
  SF_INFO info{};
  info.samplerate = rate;
  info.channels = channels;
  info.format = format;
  if (!sf_format_check(&info)) return false;
  SNDFILE* sf = sf_open(path.c_str(), SFM_WRITE, &info);
  if (sf == nullptr) return false;
  std::vector<float> x(static_cast<size_t>(frames) * channels);
  for (int i = 0; i < frames; ++i) {
    for (int c = 0; c < channels; ++c)
      x[i * channels + c] = 0.5f * std::sin(2 * 3.14159265f * 440.0f * i / rate);
  }
  sf_writef_float(sf, x.data(), frames);
  sf_close(sf);
  return true;
}

void WriteBytes(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary);
  out << bytes;
}

struct FormatCase {
  const char* name;
  int format;
};

class FormatTest : public ::testing::TestWithParam<FormatCase> {};

TEST_P(FormatTest, DecodesTone) {
  const FormatCase c = GetParam();
  const std::string path = TempPath(std::string("tone.") + c.name);
  if (!WriteTone(path, c.format, 44100, 2, 44100))
    GTEST_SKIP() << "libsndfile cannot write " << c.name;
  absl::StatusOr<DecodedAudio> audio = DecodeAudioFile(path);
  ASSERT_TRUE(audio.ok()) << audio.status();
  EXPECT_EQ(audio->sample_rate, 44100);
  EXPECT_EQ(audio->channels, 2);
  // Lossy codecs may pad the end by a frame or two.
  EXPECT_NEAR(static_cast<double>(audio->frames()), 44100.0, 4000.0);
  double sum_sq = 0.0;
  for (float v : audio->samples) sum_sq += v * v;
  EXPECT_NEAR(std::sqrt(sum_sq / audio->samples.size()), 0.5 / std::sqrt(2.0), 0.05);
}

INSTANTIATE_TEST_SUITE_P(Formats, FormatTest,
                         ::testing::Values(FormatCase{"wav", SF_FORMAT_WAV | SF_FORMAT_PCM_16},
                                           FormatCase{"flac", SF_FORMAT_FLAC | SF_FORMAT_PCM_16},
                                           FormatCase{"ogg", SF_FORMAT_OGG | SF_FORMAT_VORBIS},
                                           FormatCase{"mp3",
                                                      SF_FORMAT_MPEG | SF_FORMAT_MPEG_LAYER_III}),
                         [](const auto& test_info) { return std::string(test_info.param.name); });

TEST(Decoder, MissingFileIsNotFound) {
  EXPECT_EQ(DecodeAudioFile(TempPath("does-not-exist.wav")).status().code(),
            absl::StatusCode::kNotFound);
}

TEST(Decoder, EmptyFileIsInvalid) {
  WriteBytes(TempPath("empty.wav"), "");
  const absl::Status s = DecodeAudioFile(TempPath("empty.wav")).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("empty"), std::string::npos) << s;
}

TEST(Decoder, TextNamedWavIsInvalid) {
  WriteBytes(TempPath("text.wav"), "this is not audio, just a text file that someone named .wav\n");
  const absl::Status s = DecodeAudioFile(TempPath("text.wav")).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << s;
  EXPECT_NE(s.message().find("not a readable audio file"), std::string::npos) << s;
}

TEST(Decoder, TruncatedMp3FailsCleanlyOrGivesAPrefix) {
  const std::string path = TempPath("full.mp3");
  if (!WriteTone(path, SF_FORMAT_MPEG | SF_FORMAT_MPEG_LAYER_III, 24000, 1, 48000)) {
    GTEST_SKIP() << "libsndfile cannot write MP3";
  }
  std::ifstream in(path, std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  for (size_t keep : {size_t{10}, size_t{200}, bytes.size() / 2}) {
    const std::string cut = TempPath("cut.mp3");
    WriteBytes(cut, bytes.substr(0, keep));
    absl::StatusOr<DecodedAudio> audio = DecodeAudioFile(cut);
    if (audio.ok()) {
      // A decodable prefix: shorter than the original, finite.
      EXPECT_LT(audio->frames(), 48000) << keep;
      for (float v : audio->samples) ASSERT_TRUE(std::isfinite(v));
    } else {
      EXPECT_EQ(audio.status().code(), absl::StatusCode::kInvalidArgument) << audio.status();
    }
  }
  // Half a file still holds about half the audio.
  WriteBytes(TempPath("half.mp3"), bytes.substr(0, bytes.size() / 2));
  absl::StatusOr<DecodedAudio> half = DecodeAudioFile(TempPath("half.mp3"));
  ASSERT_TRUE(half.ok()) << half.status();
  EXPECT_GT(half->frames(), 12000);
}

TEST(Decoder, UnsupportedRateAndChannelsAreInvalid) {
  ASSERT_TRUE(WriteTone(TempPath("slow.wav"), SF_FORMAT_WAV | SF_FORMAT_PCM_16, 4000, 1, 4000));
  absl::Status s = DecodeAudioFile(TempPath("slow.wav")).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("sample rate 4000"), std::string::npos) << s;
  ASSERT_TRUE(WriteTone(TempPath("wide.wav"), SF_FORMAT_WAV | SF_FORMAT_PCM_16, 24000, 12, 100));
  s = DecodeAudioFile(TempPath("wide.wav")).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("12 channels"), std::string::npos) << s;
}

TEST(Decoder, NonFiniteFloatSamplesAreSanitised) {
  const std::string path = TempPath("nan.wav");
  SF_INFO info{};
  info.samplerate = 24000;
  info.channels = 1;
  info.format = SF_FORMAT_WAV | SF_FORMAT_FLOAT;
  SNDFILE* sf = sf_open(path.c_str(), SFM_WRITE, &info);
  ASSERT_NE(sf, nullptr);
  std::vector<float> x = {0.1f, std::numeric_limits<float>::quiet_NaN(),
                          std::numeric_limits<float>::infinity(), -0.2f};
  sf_writef_float(sf, x.data(), 4);
  sf_close(sf);
  absl::StatusOr<DecodedAudio> audio = DecodeAudioFile(path);
  ASSERT_TRUE(audio.ok()) << audio.status();
  ASSERT_EQ(audio->samples.size(), 4u);
  EXPECT_FLOAT_EQ(audio->samples[0], 0.1f);
  EXPECT_EQ(audio->samples[1], 0.0f);
  EXPECT_EQ(audio->samples[2], 0.0f);
}

TEST(Decoder, HeaderOnlyWavHasNoFrames) {
  ASSERT_TRUE(WriteTone(TempPath("zero.wav"), SF_FORMAT_WAV | SF_FORMAT_PCM_16, 24000, 1, 0));
  const absl::Status s = DecodeAudioFile(TempPath("zero.wav")).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << s;
}

}  // namespace
}  // namespace dance::engine::audio
