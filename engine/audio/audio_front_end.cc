#include "engine/audio/audio_front_end.h"

#include <algorithm>
#include <cmath>

#include "absl/strings/str_cat.h"
#include "engine/audio/decoder.h"

namespace dance::engine::audio {
namespace {
constexpr size_t kChunkFrames = 4096;  // input is processed in slices of this many frames
}  // namespace

void FeatureFrames::Clear() {
  first_index = 0;
  features.clear();
  pre.clear();
  pre_input.clear();
  beat_times_s.clear();
}

absl::StatusOr<std::unique_ptr<AudioFrontEnd>> AudioFrontEnd::Create(
    const AudioFrontEndOptions& options) {
  if (options.channels < 1 || options.channels > kMaxInputChannels) {
    return absl::InvalidArgumentError(absl::StrCat(
        "channel count ", options.channels, " is not supported (1..", kMaxInputChannels, ")"));
  }
  absl::StatusOr<std::unique_ptr<Resampler>> resampler = Resampler::Create(options.sample_rate);
  if (!resampler.ok()) return resampler.status();
  return std::unique_ptr<AudioFrontEnd>(new AudioFrontEnd(options, *std::move(resampler)));
}

AudioFrontEnd::AudioFrontEnd(const AudioFrontEndOptions& options,
                             std::unique_ptr<Resampler> resampler)
    : options_(options), resampler_(std::move(resampler)) {
  on_frame_ = [this](const FrameOutput& f) { OnFrame(f); };
  mono_.reserve(kChunkFrames);
  resampled_.reserve(kChunkFrames * kSampleRate / kMinInputRate + 8192);
}

void AudioFrontEnd::OnFrame(const FrameOutput& f) {
  if (queued_.features.empty()) queued_.first_index = f.index;
  queued_.features.insert(queued_.features.end(), f.features.begin(), f.features.end());
  queued_.pre.insert(queued_.pre.end(), f.pre.begin(), f.pre.end());
  queued_.pre_input.insert(queued_.pre_input.end(), f.pre_input.begin(), f.pre_input.end());
  if (f.beat) queued_.beat_times_s.push_back(f.beat_time_s);
}

void AudioFrontEnd::ProcessMono(absl::Span<const float> mono) {
  resampled_.clear();
  resampler_->Push(mono, &resampled_);
  extractor_.Push(resampled_, on_frame_);
}

template <typename T, typename ToFloat>
absl::Status AudioFrontEnd::PushInterleaved(absl::Span<const T> interleaved, const char* what, ToFloat to_float) {
  if (flushed_) return absl::FailedPreconditionError(absl::StrCat(what, " after Flush (call Reset first)"));
  const size_t ch = static_cast<size_t>(options_.channels);
  if (interleaved.size() % ch != 0) {
    return absl::InvalidArgumentError(absl::StrCat("chunk of ", interleaved.size(),
                                                   " samples is not a whole number of ", ch,
                                                   "-channel frames"));
  }
  const size_t frames = interleaved.size() / ch;
  for (size_t start = 0; start < frames; start += kChunkFrames) {
    const size_t n = std::min(kChunkFrames, frames - start);
    mono_.resize(n);
    for (size_t i = 0; i < n; ++i) {
      float acc = 0.0f;
      for (size_t c = 0; c < ch; ++c) acc += to_float(interleaved[(start + i) * ch + c]);
      mono_[i] = ch == 1 ? acc : acc / static_cast<float>(ch);
    }
    ProcessMono(mono_);
  }
  input_frames_ += static_cast<int64_t>(frames);
  return absl::OkStatus();
}

absl::Status AudioFrontEnd::PushFloat(absl::Span<const float> interleaved) {
  return PushInterleaved(interleaved, "PushFloat", [this](float x) {
    if (!std::isfinite(x)) {
      x = 0.0f;
      ++sanitized_samples_;
    }
    return std::clamp(x, -kMaxSampleMagnitude, kMaxSampleMagnitude);
  });
}

absl::Status AudioFrontEnd::PushInt16(absl::Span<const int16_t> interleaved) {
  return PushInterleaved(interleaved, "PushInt16",
                         [](int16_t x) { return static_cast<float>(x) * (1.0f / 32768.0f); });
}

absl::Status AudioFrontEnd::Flush() {
  if (flushed_) return absl::OkStatus();
  flushed_ = true;
  resampled_.clear();
  resampler_->Flush(&resampled_);
  extractor_.Push(resampled_, on_frame_);
  return absl::OkStatus();
}

void AudioFrontEnd::PopFrames(FeatureFrames* out, int64_t max_frames) {
  out->Clear();
  const int64_t available = queued_.frames();
  const int64_t n = max_frames < 0 ? available : std::min(available, max_frames);
  if (n == available) {
    std::swap(*out, queued_);
    queued_.Clear();
    queued_.first_index = out->first_index + n;
    return;
  }
  out->first_index = queued_.first_index;
  auto move_rows = [n](std::vector<float>* from, std::vector<float>* to, int dims) {
    to->assign(from->begin(), from->begin() + n * dims);
    from->erase(from->begin(), from->begin() + n * dims);
  };
  move_rows(&queued_.features, &out->features, kNumFeatures);
  move_rows(&queued_.pre, &out->pre, kPreDims);
  move_rows(&queued_.pre_input, &out->pre_input, kPreChannels);
  const double end_s = static_cast<double>(queued_.first_index + n) / kFrameRate;
  auto split = std::find_if(queued_.beat_times_s.begin(), queued_.beat_times_s.end(),
                            [end_s](double t) { return t > end_s; });
  out->beat_times_s.assign(queued_.beat_times_s.begin(), split);
  queued_.beat_times_s.erase(queued_.beat_times_s.begin(), split);
  queued_.first_index += n;
}

void AudioFrontEnd::Reset() {
  resampler_->Reset();
  extractor_.Reset();
  queued_.Clear();
  input_frames_ = 0;
  sanitized_samples_ = 0;
  flushed_ = false;
}

AudioFrontEndSnapshot AudioFrontEnd::Snapshot() const {
  AudioFrontEndSnapshot snap;
  snap.options = options_;
  snap.resampler = resampler_->Snapshot();
  snap.extractor = extractor_.Snapshot();
  snap.queued = queued_;
  snap.input_frames = input_frames_;
  snap.sanitized_samples = sanitized_samples_;
  snap.flushed = flushed_;
  return snap;
}

absl::Status AudioFrontEnd::Restore(const AudioFrontEndSnapshot& snap) {
  if (snap.options.sample_rate != options_.sample_rate ||
      snap.options.channels != options_.channels) {
    return absl::InvalidArgumentError(absl::StrCat(
        "snapshot was taken at ", snap.options.sample_rate, " Hz x ", snap.options.channels,
        " channels; this front end runs at ", options_.sample_rate, " Hz x ", options_.channels));
  }
  if (absl::Status s = resampler_->Restore(snap.resampler); !s.ok()) return s;
  extractor_.Restore(snap.extractor);
  queued_ = snap.queued;
  input_frames_ = snap.input_frames;
  sanitized_samples_ = snap.sanitized_samples;
  flushed_ = snap.flushed;
  return absl::OkStatus();
}

absl::StatusOr<FeatureFrames> ComputeSongFeatures(const DecodedAudio& audio, int64_t chunk_samples,
                                                  int64_t* sanitized_samples) {
  if (chunk_samples < 1) return absl::InvalidArgumentError("chunk_samples must be >= 1");
  AudioFrontEndOptions options;
  options.sample_rate = audio.sample_rate;
  options.channels = audio.channels;
  absl::StatusOr<std::unique_ptr<AudioFrontEnd>> fe = AudioFrontEnd::Create(options);
  if (!fe.ok()) return fe.status();
  FeatureFrames all, part;
  auto drain = [&]() {
    (*fe)->PopFrames(&part);
    all.features.insert(all.features.end(), part.features.begin(), part.features.end());
    all.pre.insert(all.pre.end(), part.pre.begin(), part.pre.end());
    all.pre_input.insert(all.pre_input.end(), part.pre_input.begin(), part.pre_input.end());
    all.beat_times_s.insert(all.beat_times_s.end(), part.beat_times_s.begin(), part.beat_times_s.end());
  };
  const int64_t total = audio.frames();
  for (int64_t start = 0; start < total; start += chunk_samples) {
    const int64_t n = std::min(chunk_samples, total - start);
    if (absl::Status s = (*fe)->PushFloat(absl::MakeConstSpan(audio.samples.data() + start * audio.channels,
                                                              static_cast<size_t>(n * audio.channels)));
        !s.ok()) {
      return s;
    }
    drain();
  }
  if (absl::Status s = (*fe)->Flush(); !s.ok()) return s;
  drain();
  if (sanitized_samples != nullptr) *sanitized_samples = (*fe)->sanitized_samples();
  return all;
}

}  // namespace dance::engine::audio
