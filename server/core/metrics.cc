#include "server/core/metrics.h"

#include <algorithm>
#include <cmath>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"

namespace dance::server {
namespace {

std::vector<double> LatencyBounds() {
  return {0.0005, 0.001, 0.002, 0.005, 0.01, 0.02, 0.035, 0.05, 0.075, 0.1, 0.2, 0.5, 1.0, 2.5};
}

std::vector<double> BatchBounds() { return {1, 2, 4, 8, 16, 32, 64, 128, 256, 512}; }

// Prometheus wants "snake_case" label values; absl's names are "INVALID_ARGUMENT" style.
std::string CodeLabel(int code) {
  std::string s = absl::StatusCodeToString(static_cast<absl::StatusCode>(code));
  for (char& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return s;
}

}  // namespace

Histogram::Histogram(std::vector<double> upper_bounds_s)
    : bounds_(std::move(upper_bounds_s)), buckets_(bounds_.size() + 1) {}

void Histogram::Observe(double seconds) {
  const size_t i = std::lower_bound(bounds_.begin(), bounds_.end(), seconds) - bounds_.begin();
  buckets_[i].fetch_add(1, std::memory_order_relaxed);
  sum_us_.fetch_add(static_cast<uint64_t>(std::max(0.0, seconds) * 1e6), std::memory_order_relaxed);
  count_.fetch_add(1, std::memory_order_relaxed);
}

void Histogram::Render(const std::string& name, const std::string& help, std::string* out) const {
  absl::StrAppend(out, "# HELP ", name, " ", help, "\n# TYPE ", name, " histogram\n");
  uint64_t cumulative = 0;
  for (size_t i = 0; i < bounds_.size(); ++i) {
    cumulative += buckets_[i].load(std::memory_order_relaxed);
    absl::StrAppend(out, name, "_bucket{le=\"", absl::StrFormat("%g", bounds_[i]), "\"} ", cumulative, "\n");
  }
  cumulative += buckets_.back().load(std::memory_order_relaxed);
  absl::StrAppend(out, name, "_bucket{le=\"+Inf\"} ", cumulative, "\n");
  absl::StrAppend(out, name, "_sum ", absl::StrFormat("%.6f", sum_us_.load() * 1e-6), "\n");
  absl::StrAppend(out, name, "_count ", count_.load(), "\n");
}

double Histogram::ApproxQuantile(double q) const {
  const uint64_t n = count_.load(std::memory_order_relaxed);
  if (n == 0) return 0.0;
  const uint64_t target = static_cast<uint64_t>(std::ceil(q * static_cast<double>(n)));
  uint64_t cumulative = 0;
  for (size_t i = 0; i < bounds_.size(); ++i) {
    cumulative += buckets_[i].load(std::memory_order_relaxed);
    if (cumulative >= target) return bounds_[i];
  }
  return INFINITY;
}

ServerMetrics::ServerMetrics()
    : step_latency(LatencyBounds()), frame_latency(LatencyBounds()), batch_size(BatchBounds()) {}

void ServerMetrics::CountError(absl::StatusCode code) {
  const int i = static_cast<int>(code);
  if (i > 0 && i < static_cast<int>(errors_by_code_.size())) {
    errors_by_code_[i].fetch_add(1, std::memory_order_relaxed);
  }
}

uint64_t ServerMetrics::errors(absl::StatusCode code) const {
  const int i = static_cast<int>(code);
  if (i <= 0 || i >= static_cast<int>(errors_by_code_.size())) return 0;
  return errors_by_code_[i].load(std::memory_order_relaxed);
}

std::string ServerMetrics::RenderPrometheus(int active_sessions, int max_sessions,
                                            bool draining) const {
  std::string out;
  auto counter = [&out](const char* name, const char* help, uint64_t v) {
    absl::StrAppend(&out, "# HELP ", name, " ", help, "\n# TYPE ", name, " counter\n", name, " ", v, "\n");
  };
  auto gauge = [&out](const char* name, const char* help, int64_t v) {
    absl::StrAppend(&out, "# HELP ", name, " ", help, "\n# TYPE ", name, " gauge\n", name, " ", v, "\n");
  };
  gauge("dance_sessions_active", "Live Perform sessions.", active_sessions);
  gauge("dance_sessions_max", "Admission limit (--max-sessions).", max_sessions);
  gauge("dance_viewers_active", "Live Watch subscribers (gRPC and WebSocket).", viewers_active.load());
  gauge("dance_draining", "1 while the server drains after SIGTERM.", draining ? 1 : 0);
  counter("dance_sessions_started_total", "Perform sessions admitted.", sessions_started_total.load());
  counter("dance_sessions_finished_total", "Perform sessions ended (any status).",
          sessions_finished_total.load());
  counter("dance_sessions_rejected_total", "Perform sessions refused by admission control.",
          sessions_rejected_total.load());
  counter("dance_viewers_started_total", "Watch subscriptions accepted.", viewers_started_total.load());
  counter("dance_frames_total", "Pose frames produced.", frames_total.load());
  counter("dance_viewer_frames_dropped_total", "Frames skipped for slow viewers.",
          viewer_frames_dropped_total.load());
  counter("dance_audio_samples_total", "Input audio sample frames received.", audio_samples_total.load());
  counter("dance_steps_total", "Model steps (one per session per batch).", steps_total.load());
  counter("dance_batches_total", "StepBatch calls.", batches_total.load());
  absl::StrAppend(&out, "# HELP dance_errors_total Streams ended with an error, by status code.\n",
                  "# TYPE dance_errors_total counter\n");
  for (size_t i = 1; i < errors_by_code_.size(); ++i) {
    absl::StrAppend(&out, "dance_errors_total{kind=\"", CodeLabel(static_cast<int>(i)), "\"} ",
                    errors_by_code_[i].load(std::memory_order_relaxed), "\n");
  }
  step_latency.Render("dance_step_latency_seconds", "Wall time of one batched engine step.", &out);
  frame_latency.Render("dance_frame_latency_seconds",
                       "From the arrival of the audio chunk that completed a step to its frames' publication.",
                       &out);
  batch_size.Render("dance_batch_size", "Sessions advanced per StepBatch call.", &out);
  return out;
}

}  // namespace dance::server
