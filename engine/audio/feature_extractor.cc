#include "engine/audio/feature_extractor.h"

#include <algorithm>
#include <cmath>
#include <cstring>

namespace dance::engine::audio {
namespace {
constexpr double kPi = 3.14159265358979323846;
}  // namespace

void FeatureExtractor::Push(absl::Span<const float> samples, const FrameCallback& on_frame) {
  size_t i = 0;
  while (i < samples.size()) {
    const size_t take = std::min<size_t>(kHopSamples - state_.pending, samples.size() - i);
    std::memcpy(state_.hop.data() + state_.pending, samples.data() + i, take * sizeof(float));
    state_.pending += static_cast<int>(take);
    i += take;
    if (state_.pending == kHopSamples) {
      std::memmove(state_.window.data(), state_.window.data() + kHopSamples,
                   (kWindowSamples - kHopSamples) * sizeof(float));
      std::memcpy(state_.window.data() + kWindowSamples - kHopSamples, state_.hop.data(),
                  kHopSamples * sizeof(float));
      state_.pending = 0;
      ComputeFrame(on_frame);
    }
  }
}

void FeatureExtractor::ComputeFrame(const FrameCallback& on_frame) {
  spectral_.Analyze(state_.window.data(), &spec_);
  const bool first = state_.frames == 0;
  const auto& prev_mel = first ? spec_.log_mel_db : state_.prev_log_mel;
  const auto& prev_mfcc = first ? spec_.mfcc : state_.prev_mfcc;

  float* f = frame_.features.data();
  for (int c = 0; c < kNumMfcc; ++c) {
    f[kMfccBegin + c] = spec_.mfcc[c];
    f[kDeltaMfccBegin + c] = spec_.mfcc[c] - prev_mfcc[c];
  }
  for (int c = 0; c < kNumChroma; ++c) f[kChromaBegin + c] = spec_.chroma[c];
  float flux = 0.0f, high_flux = 0.0f, low = 0.0f;
  for (int b = 0; b < kNumMelBands; ++b) {
    const float rise = std::max(0.0f, spec_.log_mel_db[b] - prev_mel[b]);
    flux += rise;
    if (b >= kHighBandBegin) high_flux += rise;
    if (b < kLowBandEnd) low += spec_.log_mel_db[b];
  }
  flux /= kNumMelBands;
  high_flux /= (kNumMelBands - kHighBandBegin);
  low /= kLowBandEnd;
  f[kOnsetIndex] = flux;
  f[kRmsDbIndex] = spec_.rms_db;

  beat_.Update(flux, &beat_out_);
  for (int i = 0; i < kNumTempogram; ++i) f[kTempogramBegin + i] = beat_out_.tempogram[i];
  f[kBeatPhaseCosIndex] = static_cast<float>(std::cos(2.0 * kPi * beat_out_.beat_phase));
  f[kBeatPhaseSinIndex] = static_cast<float>(std::sin(2.0 * kPi * beat_out_.beat_phase));
  f[kTempoIndex] = static_cast<float>(std::log2(beat_out_.tempo_bpm / 120.0));
  f[kBarPhaseCosIndex] = static_cast<float>(std::cos(2.0 * kPi * beat_out_.bar_phase));
  f[kBarPhaseSinIndex] = static_cast<float>(std::sin(2.0 * kPi * beat_out_.bar_phase));
  f[kBeatConfidenceIndex] = static_cast<float>(beat_out_.confidence);

  frame_.pre_input = {flux, spec_.rms_db / 10.0f, low / 10.0f, high_flux};
  pre_.Update(frame_.pre_input, absl::MakeSpan(frame_.pre));

  frame_.index = state_.frames;
  frame_.beat = beat_out_.beat;
  frame_.beat_time_s =
      (static_cast<double>(state_.frames + 1) - beat_out_.beat_offset_frames) / kFrameRate;
  state_.prev_log_mel = spec_.log_mel_db;
  state_.prev_mfcc = spec_.mfcc;
  ++state_.frames;
  on_frame(frame_);
}

void FeatureExtractor::Reset() {
  state_ = FeatureExtractorState{};
  beat_.Reset();
  pre_.Reset();
}

// The beat tracker and PRE keep their own state while running (no per-frame copies); a snapshot
// gathers it into one value.
FeatureExtractorState FeatureExtractor::Snapshot() const {
  FeatureExtractorState state = state_;
  state.beat = beat_.state();
  state.pre = pre_.state();
  return state;
}

void FeatureExtractor::Restore(const FeatureExtractorState& state) {
  state_ = state;
  beat_.set_state(state.beat);
  pre_.set_state(state.pre);
}

}  // namespace dance::engine::audio
