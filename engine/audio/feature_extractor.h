// Causal feature extractor for the internal stream (mono, 24 kHz): every kHopSamples new samples it
// produces one feature frame (kNumFeatures floats, layout in feature_layout.h / docs/features.md),
// the frame's PRE input channels (kPreChannels) and its PRE frame (kPreDims).
//
//   FeatureExtractor fx;
//   fx.Push(samples, [&](const FrameOutput& f) { ... });   // called once per completed frame, in
//   order
//
// Frame n depends on samples [0, (n + 1) * kHopSamples) only; samples before the stream start are
// 0. Output depends only on the sample values, never on how they were chunked. Not thread-safe (one
// owner); distinct extractors may run on different threads. No allocation after construction.
#ifndef DANCE_ENGINE_AUDIO_FEATURE_EXTRACTOR_H_
#define DANCE_ENGINE_AUDIO_FEATURE_EXTRACTOR_H_

#include <array>
#include <cstdint>
#include <functional>

#include "absl/types/span.h"
#include "engine/audio/beat_tracker.h"
#include "engine/audio/feature_layout.h"
#include "engine/audio/incremental_pre.h"
#include "engine/audio/spectral.h"

namespace dance::engine::audio {

struct FrameOutput {
  int64_t index = 0;  // frame index since the stream start
  std::array<float, kNumFeatures> features;
  std::array<float, kPreChannels> pre_input;  // the PRE rhythm channels of this frame
  std::array<float, kPreDims> pre;
  bool beat = false;         // a beat happened within this frame
  double beat_time_s = 0.0;  // if beat: its time on the 24 kHz timeline, seconds
};

// Everything the extractor remembers (a plain copyable value: snapshot = copy).
struct FeatureExtractorState {
  std::array<float, kWindowSamples> window{};  // last kWindowSamples samples, oldest first
  int pending = 0;                             // samples of the next hop already in `hop`
  std::array<float, kHopSamples> hop{};
  std::array<float, kNumMelBands> prev_log_mel{};
  std::array<float, kNumMfcc> prev_mfcc{};
  int64_t frames = 0;
  BeatTrackerState beat;    // filled by Snapshot(); the live copy sits in the BeatTracker
  IncrementalPreState pre;  // filled by Snapshot(); the live copy sits in the IncrementalPre
};

class FeatureExtractor {
 public:
  using FrameCallback = std::function<void(const FrameOutput&)>;

  FeatureExtractor() = default;
  FeatureExtractor(const FeatureExtractor&) = delete;
  FeatureExtractor& operator=(const FeatureExtractor&) = delete;

  // Appends samples (finite, mono, 24 kHz); calls `on_frame` for each frame completed.
  void Push(absl::Span<const float> samples, const FrameCallback& on_frame);

  void Reset();
  FeatureExtractorState Snapshot() const;
  void Restore(const FeatureExtractorState& state);
  int64_t frames() const { return state_.frames; }

 private:
  void ComputeFrame(const FrameCallback& on_frame);

  FeatureExtractorState state_;
  SpectralAnalyzer spectral_;
  BeatTracker beat_;
  IncrementalPre pre_;
  SpectralFrame spec_;          // scratch
  BeatTrackerOutput beat_out_;  // scratch
  FrameOutput frame_;           // scratch
};

// The PRE channels computed from one frame (exposed for docs and tests):
//   0: onset strength (dB);  1: RMS dB / 10;  2: mean log-mel dB of bands [0, kLowBandEnd) / 10;
//   3: high-band flux: mean over bands [kHighBandBegin, 64) of max(0, log-mel dB increase).

}  // namespace dance::engine::audio

#endif  // DANCE_ENGINE_AUDIO_FEATURE_EXTRACTOR_H_
