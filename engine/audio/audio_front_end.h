// The streaming audio front end: PCM chunks of any size in, 30 fps feature and PRE frames out.
//
//   AudioFrontEndOptions options;
//   options.sample_rate = 44100;  // Hz, 8000..96000
//   options.channels = 2;         // 1..8, interleaved
//   absl::StatusOr<std::unique_ptr<AudioFrontEnd>> fe = AudioFrontEnd::Create(options);
//   RETURN_IF_ERROR((*fe)->PushFloat(chunk));          // or PushInt16; any length, even 1 sample
//   FeatureFrames frames;
//   (*fe)->PopFrames(&frames);                          // frames completed so far, in order
//   ...
//   (*fe)->Flush();                                     // end of audio: drains the resampler
//
// Pipeline: downmix (mean of channels) -> resample to 24 kHz (resampler.h) -> FeatureExtractor.
// Guarantees: frame n depends only on input up to the end of its hop (declared lookahead 0: the
// resampler uses a minimum-phase filter); the output is bit-identical whatever the chunking.
// Non-finite input samples (NaN, +-Inf) are sanitised to 0 and counted (sanitized_samples());
// finite samples are clamped to [-kMaxSampleMagnitude, kMaxSampleMagnitude] so that powers stay
// finite. Int16 samples are scaled by 1/32768. Ownership and threads: one owner at a time (not
// thread-safe); independent instances may run on different threads. Push does not allocate per
// frame once the output vectors have grown.
#ifndef DANCE_ENGINE_AUDIO_AUDIO_FRONT_END_H_
#define DANCE_ENGINE_AUDIO_AUDIO_FRONT_END_H_

#include <cstdint>
#include <memory>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/types/span.h"
#include "engine/audio/decoder.h"
#include "engine/audio/feature_extractor.h"
#include "engine/audio/feature_layout.h"
#include "engine/audio/resampler.h"

namespace dance::engine::audio {

inline constexpr float kMaxSampleMagnitude = 16.0f;

struct AudioFrontEndOptions {
  int sample_rate = kSampleRate;  // Hz of the pushed PCM, 8000..96000
  int channels = 1;               // interleaved channels of the pushed PCM, 1..8
};

// Frames handed out by PopFrames. Arrays are row-major.
struct FeatureFrames {
  int64_t first_index = 0;       // frame index (since stream start) of row 0
  std::vector<float> features;   // (frames, kNumFeatures)
  std::vector<float> pre;        // (frames, kPreDims)
  std::vector<float> pre_input;  // (frames, kPreChannels): PRE's input channels (for the reference)
  std::vector<double>
      beat_times_s;  // beats detected in these frames, seconds on the stream timeline
  int64_t frames() const { return static_cast<int64_t>(features.size()) / kNumFeatures; }
  void Clear();
};

// All state of a front end, for session snapshot/resume. Opaque to callers; copyable.
struct AudioFrontEndSnapshot {
  AudioFrontEndOptions options;
  ResamplerSnapshot resampler;
  FeatureExtractorState extractor;
  FeatureFrames queued;  // frames completed but not yet popped
  int64_t input_frames = 0;
  int64_t sanitized_samples = 0;
  bool flushed = false;
};

class AudioFrontEnd {
 public:
  // InvalidArgument for a rate outside 8000..96000 Hz or channels outside 1..8.
  static absl::StatusOr<std::unique_ptr<AudioFrontEnd>> Create(const AudioFrontEndOptions& options);

  // Push interleaved PCM; the length must be a multiple of the channel count (InvalidArgument
  // otherwise, nothing consumed). FailedPrecondition after Flush (until Reset).
  absl::Status PushFloat(absl::Span<const float> interleaved);
  absl::Status PushInt16(absl::Span<const int16_t> interleaved);
  // End of audio: resamples what the resampler still buffers. A partial last hop is not a frame.
  absl::Status Flush();

  int64_t FramesReady() const { return queued_.frames(); }
  // Moves up to `max_frames` (all if < 0) queued frames into `out` (cleared first).
  void PopFrames(FeatureFrames* out, int64_t max_frames = -1);

  void Reset();
  AudioFrontEndSnapshot Snapshot() const;
  // InvalidArgument if the snapshot was taken with different options.
  absl::Status Restore(const AudioFrontEndSnapshot& snapshot);

  // Declared lookahead in 24 kHz samples: 0 (see header comment).
  static constexpr int LookaheadSamples() { return 0; }
  // Input buffering before resampling (latency, not lookahead), in input samples.
  int BufferingSamples() const { return resampler_->BufferingSamples(); }
  int64_t frames_produced() const { return extractor_.frames(); }
  int64_t input_frames() const { return input_frames_; }
  int64_t sanitized_samples() const { return sanitized_samples_; }
  const AudioFrontEndOptions& options() const { return options_; }

 private:
  AudioFrontEnd(const AudioFrontEndOptions& options, std::unique_ptr<Resampler> resampler);
  void ProcessMono(absl::Span<const float> mono);
  // Checks, downmixes (converting each sample with to_float) and processes an interleaved chunk.
  template <typename T, typename ToFloat>
  absl::Status PushInterleaved(absl::Span<const T> interleaved, const char* what, ToFloat to_float);
  void OnFrame(const FrameOutput& frame);

  AudioFrontEndOptions options_;
  std::unique_ptr<Resampler> resampler_;
  FeatureExtractor extractor_;
  FeatureExtractor::FrameCallback on_frame_;
  FeatureFrames queued_;
  std::vector<float> mono_;       // scratch: downmixed input
  std::vector<float> resampled_;  // scratch: 24 kHz output of the resampler
  int64_t input_frames_ = 0;
  int64_t sanitized_samples_ = 0;
  bool flushed_ = false;
};

// Every frame of a whole decoded song, pushed in chunks of `chunk_samples` input frames (the features do not
// depend on the chunking) and flushed at the end: what dance-features writes and the diffusion editor reads.
// `sanitized_samples`, if set, receives AudioFrontEnd::sanitized_samples() at the end.
absl::StatusOr<FeatureFrames> ComputeSongFeatures(const DecodedAudio& audio, int64_t chunk_samples = 1 << 16,
                                                  int64_t* sanitized_samples = nullptr);

}  // namespace dance::engine::audio

#endif  // DANCE_ENGINE_AUDIO_AUDIO_FRONT_END_H_
