#include "client/audio_source.h"

#include <portaudio.h>
#include <sndfile.h>

#include <algorithm>
#include <cstring>

#include "absl/strings/str_cat.h"

namespace dance::client {

absl::StatusOr<std::shared_ptr<const AudioClip>> ReadAudioFile(const std::string& path) {
  SF_INFO info{};
  SNDFILE* f = sf_open(path.c_str(), SFM_READ, &info);
  if (f == nullptr) return absl::NotFoundError(absl::StrCat("cannot open audio ", path, ": ", sf_strerror(nullptr)));
  auto clip = std::make_shared<AudioClip>();
  clip->sample_rate = info.samplerate;
  clip->channels = info.channels;
  clip->samples.resize(static_cast<size_t>(info.frames) * info.channels);
  const sf_count_t got = sf_readf_float(f, clip->samples.data(), info.frames);
  sf_close(f);
  clip->samples.resize(static_cast<size_t>(got) * info.channels);
  if (got <= 0) return absl::InvalidArgumentError(absl::StrCat(path, " has no audio"));
  return clip;
}

ClipSource::ClipSource(std::shared_ptr<const AudioClip> clip, bool realtime, double duration_s)
    : clip_(std::move(clip)), realtime_(realtime) {
  total_ = duration_s > 0 ? static_cast<int64_t>(duration_s * clip_->sample_rate) : clip_->frames();
}

int64_t ClipSource::Available(absl::Time now) {
  if (!realtime_) return total_;
  const int64_t due = static_cast<int64_t>(absl::ToDoubleSeconds(now - t0_) * clip_->sample_rate);
  return std::clamp<int64_t>(due, 0, total_);
}

void ClipSource::Read(int64_t offset, int64_t n, std::vector<float>* out) {
  const int c = clip_->channels;
  out->resize(static_cast<size_t>(n) * c);
  const int64_t len = clip_->frames();
  int64_t done = 0;
  while (done < n) {
    const int64_t pos = (offset + done) % len;
    const int64_t run = std::min(n - done, len - pos);
    std::memcpy(out->data() + done * c, clip_->samples.data() + pos * c, static_cast<size_t>(run * c) * sizeof(float));
    done += run;
  }
}

namespace {

bool EnsurePortAudio() {
  static const bool ok = Pa_Initialize() == paNoError;
  return ok;
}

int MicCallback(const void* input, void*, unsigned long frames, const PaStreamCallbackTimeInfo*,
                PaStreamCallbackFlags, void* user) {
  static_cast<MicSource*>(user)->Append(static_cast<const float*>(input), static_cast<int64_t>(frames));
  return paContinue;
}

int PlayCallback(const void*, void* output, unsigned long frames, const PaStreamCallbackTimeInfo*,
                 PaStreamCallbackFlags, void* user) {
  static_cast<Playback*>(user)->Fill(static_cast<float*>(output), frames);
  return paContinue;
}

}  // namespace

absl::StatusOr<std::unique_ptr<MicSource>> MicSource::Open(int sample_rate, double max_seconds) {
  if (!EnsurePortAudio()) return absl::UnavailableError("PortAudio failed to initialise");
  std::unique_ptr<MicSource> m(new MicSource(sample_rate));
  m->max_frames_ = static_cast<int64_t>(max_seconds * sample_rate);
  PaStream* stream = nullptr;
  PaError err = Pa_OpenDefaultStream(&stream, 1, 0, paFloat32, sample_rate, 256, MicCallback, m.get());
  if (err != paNoError) return absl::UnavailableError(absl::StrCat("no microphone: ", Pa_GetErrorText(err)));
  m->stream_ = stream;
  return m;
}

MicSource::~MicSource() {
  if (stream_ != nullptr) {
    Pa_StopStream(static_cast<PaStream*>(stream_));
    Pa_CloseStream(static_cast<PaStream*>(stream_));
  }
}

void MicSource::Start(absl::Time) { Pa_StartStream(static_cast<PaStream*>(stream_)); }

void MicSource::Append(const float* data, int64_t n) {
  absl::MutexLock lock(&mu_);
  if (stopped_) return;
  buffer_.insert(buffer_.end(), data, data + n);
  if (max_frames_ > 0 && static_cast<int64_t>(buffer_.size()) >= max_frames_) stopped_ = true;
}

void MicSource::Stop() {
  absl::MutexLock lock(&mu_);
  stopped_ = true;
}

int64_t MicSource::Available(absl::Time) {
  absl::MutexLock lock(&mu_);
  return static_cast<int64_t>(buffer_.size());
}

int64_t MicSource::Total() const {
  absl::MutexLock lock(&mu_);
  return stopped_ ? static_cast<int64_t>(buffer_.size()) : -1;
}

void MicSource::Read(int64_t offset, int64_t n, std::vector<float>* out) {
  absl::MutexLock lock(&mu_);
  out->assign(buffer_.begin() + offset, buffer_.begin() + offset + n);
}

absl::StatusOr<std::unique_ptr<Playback>> Playback::Start(std::shared_ptr<const AudioClip> clip) {
  if (!EnsurePortAudio()) return absl::UnavailableError("PortAudio failed to initialise");
  std::unique_ptr<Playback> p(new Playback());
  p->clip_ = std::move(clip);
  PaStream* stream = nullptr;
  PaError err = Pa_OpenDefaultStream(&stream, 0, p->clip_->channels, paFloat32, p->clip_->sample_rate, 256,
                                     PlayCallback, p.get());
  if (err != paNoError) return absl::UnavailableError(absl::StrCat("no audio output: ", Pa_GetErrorText(err)));
  p->stream_ = stream;
  Pa_StartStream(stream);
  return p;
}

Playback::~Playback() {
  if (stream_ != nullptr) {
    Pa_StopStream(static_cast<PaStream*>(stream_));
    Pa_CloseStream(static_cast<PaStream*>(stream_));
  }
}

void Playback::Fill(float* out, unsigned long frames) {
  const int c = clip_->channels;
  const int64_t n = std::min<int64_t>(static_cast<int64_t>(frames), clip_->frames() - position_);
  if (n > 0) std::memcpy(out, clip_->samples.data() + position_ * c, static_cast<size_t>(n * c) * sizeof(float));
  if (n < static_cast<int64_t>(frames)) {
    std::memset(out + std::max<int64_t>(n, 0) * c, 0, static_cast<size_t>((frames - std::max<int64_t>(n, 0)) * c) * sizeof(float));
  }
  position_ += std::max<int64_t>(n, 0);
}

}  // namespace dance::client
