// Decodes whole audio files (WAV, FLAC, OGG/Vorbis, MP3, and anything else libsndfile reads) to
// interleaved float32 PCM at the file's own rate and channel count.
//
//   absl::StatusOr<DecodedAudio> audio = DecodeAudioFile("song.ogg");
//   if (!audio.ok()) return audio.status();
//   // audio->samples: interleaved, audio->channels per frame, audio->sample_rate Hz.
//
// Errors: NotFound (missing file), InvalidArgument (empty, truncated beyond recovery, not audio, a
// rate outside [kMinInputRate, kMaxInputRate], channel count outside [1, kMaxInputChannels]).
// Non-finite samples (possible in float WAV files) are replaced by 0 (sanitised, as AudioFrontEnd
// does). Thread-safe: no shared state.
#ifndef DANCE_ENGINE_AUDIO_DECODER_H_
#define DANCE_ENGINE_AUDIO_DECODER_H_

#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "absl/types/span.h"

namespace dance::engine::audio {

inline constexpr int kMinInputRate = 8000;   // Hz
inline constexpr int kMaxInputRate = 96000;  // Hz
inline constexpr int kMaxInputChannels = 8;
// Whole-file decoding holds every sample in memory: at most 2^28 samples (1 GiB of float32, e.g. 50
// min of 44.1 kHz stereo or 3 h of 24 kHz mono). Longer audio should be streamed through
// AudioFrontEnd.
inline constexpr int64_t kMaxDecodedSamples = int64_t{1} << 28;
inline constexpr int64_t kMaxDecodedFrames =
    kMaxDecodedSamples;  // per channel; the sample bound also applies

struct DecodedAudio {
  std::vector<float> samples;  // (frames, channels) interleaved, nominally in [-1, 1]
  int sample_rate = 0;         // Hz
  int channels = 0;
  int64_t frames() const {
    return channels > 0 ? static_cast<int64_t>(samples.size()) / channels : 0;
  }
  double duration_s() const {
    return sample_rate > 0 ? static_cast<double>(frames()) / sample_rate : 0.0;
  }
};

// Decodes the file at `path`.
absl::StatusOr<DecodedAudio> DecodeAudioFile(const std::string& path);

// Decodes an encoded file held in memory (same formats and errors as DecodeAudioFile). `name` is
// only used in error messages. `max_frames` bounds the decoded length (fuzzing uses a small bound).
absl::StatusOr<DecodedAudio> DecodeAudioMemory(absl::Span<const uint8_t> bytes,
                                               const std::string& name = "<memory>",
                                               int64_t max_frames = kMaxDecodedFrames);

}  // namespace dance::engine::audio

#endif  // DANCE_ENGINE_AUDIO_DECODER_H_
