// Streaming mono resampler from any rate in [8, 96] kHz to 24 kHz (libsoxr, high quality, minimum
// phase).
//
// Causality: soxr aligns its output on the filter peak, so a sample's response starts slightly
// before its time. The output stream therefore starts with DelaySamples() zeros (measured per rate
// with impulses: 3-5 samples at 32-48 kHz, up to ~190 at 8 kHz), after which output sample j
// depends only on input up to time j / 24000 s (up to FFT round-off inside soxr, below 1e-6 of the
// signal level).
//
// Chunking invariance: input is collected into fixed blocks (about 10 ms, a whole number of output
// samples each) and soxr only ever sees those blocks, so the output is bit-identical however the
// caller chunks the input. At 24 kHz input it is a pass-through (no filtering, no delay).
// Snapshot/Restore: soxr state cannot be copied, so a snapshot keeps the last ~100 ms of input and
// the counters; Restore builds a fresh soxr, replays that history (discarding its output) and
// continues. The filter's memory is shorter than the history, so the continuation matches (tested
// to 1e-6). Not thread-safe; no allocation on Push after construction (except the caller's output
// vector growth).
#ifndef DANCE_ENGINE_AUDIO_RESAMPLER_H_
#define DANCE_ENGINE_AUDIO_RESAMPLER_H_

#include <cstdint>
#include <memory>
#include <vector>

#include "absl/status/statusor.h"
#include "absl/types/span.h"

namespace dance::engine::audio {

struct ResamplerSnapshot {
  int input_rate = 0;
  std::vector<float> history;  // last fed blocks (whole blocks), oldest first
  std::vector<float> pending;  // input not yet forming a whole block
  int64_t blocks_fed = 0;
};

class Resampler {
 public:
  // InvalidArgument unless 8000 <= input_rate <= 96000.
  static absl::StatusOr<std::unique_ptr<Resampler>> Create(int input_rate);
  ~Resampler();

  // Appends 24 kHz output for `input` (mono) to `out`.
  void Push(absl::Span<const float> input, std::vector<float>* out);
  // End of stream: resamples the partial block and drains the filter into `out`.
  void Flush(std::vector<float>* out);
  void Reset();
  ResamplerSnapshot Snapshot() const;
  absl::Status Restore(const ResamplerSnapshot& snapshot);

  int input_rate() const { return input_rate_; }
  int block_samples() const { return block_; }
  // Input samples buffered before they are resampled (latency, not lookahead): block_samples() - 1.
  int BufferingSamples() const { return passthrough_ ? 0 : block_ - 1; }
  // Zeros prepended to the 24 kHz output (latency that keeps the output causal); 0 at 24 kHz.
  int DelaySamples() const { return delay_; }

 private:
  explicit Resampler(int input_rate);
  absl::Status Open();
  void FeedBlock(const float* block, int length, std::vector<float>* out);

  int input_rate_;
  bool passthrough_;
  int block_ = 0;           // input samples per block
  int history_blocks_ = 0;  // blocks kept for Snapshot
  struct SoxrDeleter {
    void operator()(void* p) const;
  };
  std::unique_ptr<void, SoxrDeleter> soxr_;
  std::vector<float> pending_;  // capacity block_
  std::vector<float> history_;  // ring of history_blocks_ * block_ samples
  int64_t blocks_fed_ = 0;
  int delay_ = 0;
  bool delay_emitted_ = false;
  std::vector<float> scratch_;  // soxr output scratch
};

}  // namespace dance::engine::audio

#endif  // DANCE_ENGINE_AUDIO_RESAMPLER_H_
