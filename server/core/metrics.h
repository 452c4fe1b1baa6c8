// Process-wide server metrics: counters, gauges and histograms, written by every layer. The HTTP transport
// renders them for Prometheus (server/web/prometheus.h).
//
// Usage:
//   ServerMetrics m;
//   m.frames_total.fetch_add(4);
//   m.step_latency.Observe(0.0031);            // seconds
//   m.CountError(absl::StatusCode::kInvalidArgument);
//   uint64_t n = m.errors(absl::StatusCode::kInvalidArgument);
//
// Thread safety: every member is lock-free atomic; all methods may be called from any thread.
#ifndef DANCE_SERVER_CORE_METRICS_H_
#define DANCE_SERVER_CORE_METRICS_H_

#include <array>
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "absl/status/status.h"

namespace dance::server {

// A histogram with fixed upper bounds (seconds). Observations are recorded in microseconds internally so
// the sum stays an integer atomic.
class Histogram {
 public:
  explicit Histogram(std::vector<double> upper_bounds_s);
  void Observe(double seconds);
  uint64_t count() const { return count_.load(std::memory_order_relaxed); }
  // Upper bounds, seconds; observations in bucket i (i == bounds().size(): above the last bound, +Inf);
  // sum of all observations, microseconds.
  const std::vector<double>& bounds() const { return bounds_; }
  uint64_t bucket(size_t i) const { return buckets_[i].load(std::memory_order_relaxed); }
  uint64_t sum_us() const { return sum_us_.load(std::memory_order_relaxed); }
  // Approximate quantile (upper bound of the bucket holding it), seconds; 0 if empty.
  double ApproxQuantile(double q) const;

 private:
  std::vector<double> bounds_;
  std::vector<std::atomic<uint64_t>> buckets_;  // bounds_.size() + 1 (+Inf)
  std::atomic<uint64_t> sum_us_{0};
  std::atomic<uint64_t> count_{0};
};

struct ServerMetrics {
  ServerMetrics();

  std::atomic<uint64_t> sessions_started_total{0};
  std::atomic<uint64_t> sessions_finished_total{0};
  std::atomic<uint64_t> sessions_rejected_total{0};   // admission control
  std::atomic<uint64_t> viewers_started_total{0};
  std::atomic<int64_t> viewers_active{0};            // gauge: live gRPC + WebSocket viewers
  std::atomic<uint64_t> frames_total{0};              // frames produced by the engine
  std::atomic<uint64_t> beats_total{0};               // KIND_BEAT events published
  std::atomic<uint64_t> viewer_frames_dropped_total{0};
  std::atomic<uint64_t> audio_samples_total{0};       // input sample frames received
  std::atomic<uint64_t> steps_total{0};
  std::atomic<uint64_t> batches_total{0};
  Histogram step_latency;    // seconds per StepBatch call
  Histogram frame_latency;   // seconds from the triggering chunk's arrival to frame publication
  Histogram batch_size;      // sessions per StepBatch (unitless, buckets 1..512)

  // Streams ended with an error, by status code (1 .. kMaxStatusCode; OK and unknown codes are not counted).
  static constexpr int kMaxStatusCode = 16;
  void CountError(absl::StatusCode code);
  uint64_t errors(absl::StatusCode code) const;

 private:
  std::array<std::atomic<uint64_t>, kMaxStatusCode + 1> errors_by_code_{};
};

}  // namespace dance::server

#endif  // DANCE_SERVER_CORE_METRICS_H_
