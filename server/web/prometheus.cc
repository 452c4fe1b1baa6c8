#include "server/web/prometheus.h"

#include <cctype>
#include <cstdint>
#include <vector>

#include "absl/status/status.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"

namespace dance::server {
namespace {

// Prometheus wants "snake_case" label values; absl's names are "INVALID_ARGUMENT" style.
std::string CodeLabel(int code) {
  std::string s = absl::StatusCodeToString(static_cast<absl::StatusCode>(code));
  for (char& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return s;
}

}  // namespace

void RenderHistogram(const Histogram& h, const std::string& name, const std::string& help, std::string* out) {
  absl::StrAppend(out, "# HELP ", name, " ", help, "\n# TYPE ", name, " histogram\n");
  const std::vector<double>& bounds = h.bounds();
  uint64_t cumulative = 0;
  for (size_t i = 0; i < bounds.size(); ++i) {
    cumulative += h.bucket(i);
    absl::StrAppend(out, name, "_bucket{le=\"", absl::StrFormat("%g", bounds[i]), "\"} ", cumulative, "\n");
  }
  cumulative += h.bucket(bounds.size());
  absl::StrAppend(out, name, "_bucket{le=\"+Inf\"} ", cumulative, "\n");
  absl::StrAppend(out, name, "_sum ", absl::StrFormat("%.6f", h.sum_us() * 1e-6), "\n");
  absl::StrAppend(out, name, "_count ", h.count(), "\n");
}

std::string RenderPrometheus(const ServerMetrics& m, int active_sessions, int max_sessions, bool draining) {
  std::string out;
  auto counter = [&out](const char* name, const char* help, uint64_t v) {
    absl::StrAppend(&out, "# HELP ", name, " ", help, "\n# TYPE ", name, " counter\n", name, " ", v, "\n");
  };
  auto gauge = [&out](const char* name, const char* help, int64_t v) {
    absl::StrAppend(&out, "# HELP ", name, " ", help, "\n# TYPE ", name, " gauge\n", name, " ", v, "\n");
  };
  gauge("dance_sessions_active", "Live Perform sessions.", active_sessions);
  gauge("dance_sessions_max", "Admission limit (--max-sessions).", max_sessions);
  gauge("dance_viewers_active", "Live Watch subscribers (gRPC and WebSocket).", m.viewers_active.load());
  gauge("dance_draining", "1 while the server drains after SIGTERM.", draining ? 1 : 0);
  counter("dance_sessions_started_total", "Perform sessions admitted.", m.sessions_started_total.load());
  counter("dance_sessions_finished_total", "Perform sessions ended (any status).",
          m.sessions_finished_total.load());
  counter("dance_sessions_rejected_total", "Perform sessions refused by admission control.",
          m.sessions_rejected_total.load());
  counter("dance_viewers_started_total", "Watch subscriptions accepted.", m.viewers_started_total.load());
  counter("dance_frames_total", "Pose frames produced.", m.frames_total.load());
  counter("dance_beats_total", "Beats detected and sent as KIND_BEAT events.", m.beats_total.load());
  counter("dance_viewer_frames_dropped_total", "Frames skipped for slow viewers.",
          m.viewer_frames_dropped_total.load());
  counter("dance_audio_samples_total", "Input audio sample frames received.", m.audio_samples_total.load());
  counter("dance_steps_total", "Model steps (one per session per batch).", m.steps_total.load());
  counter("dance_batches_total", "StepBatch calls.", m.batches_total.load());
  absl::StrAppend(&out, "# HELP dance_errors_total Streams ended with an error, by status code.\n",
                  "# TYPE dance_errors_total counter\n");
  for (int code = 1; code <= ServerMetrics::kMaxStatusCode; ++code) {
    absl::StrAppend(&out, "dance_errors_total{kind=\"", CodeLabel(code), "\"} ",
                    m.errors(static_cast<absl::StatusCode>(code)), "\n");
  }
  RenderHistogram(m.step_latency, "dance_step_latency_seconds", "Wall time of one batched engine step.", &out);
  RenderHistogram(m.frame_latency, "dance_frame_latency_seconds",
                  "From the arrival of the audio chunk that completed a step to its frames' publication.", &out);
  RenderHistogram(m.batch_size, "dance_batch_size", "Sessions advanced per StepBatch call.", &out);
  return out;
}

}  // namespace dance::server
