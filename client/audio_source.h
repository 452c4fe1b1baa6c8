// Audio for the client: decoding a file (libsndfile: WAV, FLAC, Ogg/Vorbis, ...) and the sources the
// perform stream pulls from: a file paced in real time, a file as fast as possible, or the microphone.
//
// Usage:
//   ASSIGN_OR_RETURN(std::shared_ptr<const AudioClip> clip, ReadAudioFile("song.ogg"));
//   auto src = std::make_unique<ClipSource>(clip, /*realtime=*/true, /*duration_s=*/0);
//   src->Start(absl::Now());  ...  int64_t n = src->Available(absl::Now());  src->Read(offset, n, &buf);
//
// Thread safety: ClipSource is immutable after Start (any thread). MicSource's ring buffer is filled by
// PortAudio's thread and read by one reader thread.
#ifndef DANCE_CLIENT_AUDIO_SOURCE_H_
#define DANCE_CLIENT_AUDIO_SOURCE_H_

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "absl/base/thread_annotations.h"
#include "absl/status/statusor.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"

namespace dance::client {

struct AudioClip {
  int sample_rate = 0;       // Hz
  int channels = 0;
  std::vector<float> samples;  // interleaved, frames * channels
  int64_t frames() const { return channels > 0 ? static_cast<int64_t>(samples.size()) / channels : 0; }
};

absl::StatusOr<std::shared_ptr<const AudioClip>> ReadAudioFile(const std::string& path);

class SampleSource {
 public:
  virtual ~SampleSource() = default;
  virtual int sample_rate() const = 0;
  virtual int channels() const = 0;
  virtual void Start(absl::Time t0) = 0;
  // Sample frames available from stream start up to `now` (monotone).
  virtual int64_t Available(absl::Time now) = 0;
  // Total frames, or -1 while unknown (microphone until stopped).
  virtual int64_t Total() const = 0;
  // Copies frames [offset, offset + n) interleaved into *out (resized).
  virtual void Read(int64_t offset, int64_t n, std::vector<float>* out) = 0;
};

// A clip, looped if duration_s exceeds it (duration_s 0 = the clip once).
class ClipSource : public SampleSource {
 public:
  ClipSource(std::shared_ptr<const AudioClip> clip, bool realtime, double duration_s);
  int sample_rate() const override { return clip_->sample_rate; }
  int channels() const override { return clip_->channels; }
  void Start(absl::Time t0) override { t0_ = t0; }
  int64_t Available(absl::Time now) override;
  int64_t Total() const override { return total_; }
  void Read(int64_t offset, int64_t n, std::vector<float>* out) override;

 private:
  std::shared_ptr<const AudioClip> clip_;
  bool realtime_;
  int64_t total_;
  absl::Time t0_;
};

// The default input device through PortAudio, mono float at `sample_rate`, until Stop().
class MicSource : public SampleSource {
 public:
  static absl::StatusOr<std::unique_ptr<MicSource>> Open(int sample_rate, double max_seconds);
  ~MicSource() override;
  int sample_rate() const override { return sample_rate_; }
  int channels() const override { return 1; }
  void Start(absl::Time t0) override;
  int64_t Available(absl::Time now) override;
  int64_t Total() const override;
  void Read(int64_t offset, int64_t n, std::vector<float>* out) override;
  void Stop();
  // PortAudio's callback (internal).
  void Append(const float* data, int64_t n);

 private:
  explicit MicSource(int sample_rate) : sample_rate_(sample_rate) {}
  const int sample_rate_;
  void* stream_ = nullptr;  // PaStream*
  int64_t max_frames_ = 0;
  mutable absl::Mutex mu_;
  std::vector<float> buffer_ ABSL_GUARDED_BY(mu_);
  bool stopped_ ABSL_GUARDED_BY(mu_) = false;
};

// Plays a clip on the default output device from `t0` (best effort, for --play). Returns a handle that
// stops playback when destroyed.
class Playback {
 public:
  static absl::StatusOr<std::unique_ptr<Playback>> Start(std::shared_ptr<const AudioClip> clip);
  ~Playback();
  void Fill(float* out, unsigned long frames);  // PortAudio's callback (internal)

 private:
  std::shared_ptr<const AudioClip> clip_;
  int64_t position_ = 0;
  void* stream_ = nullptr;
};

}  // namespace dance::client

#endif  // DANCE_CLIENT_AUDIO_SOURCE_H_
