// SessionHub: the registry of live sessions, admission control and the scheduler pool.
//
// Admit() validates nothing about the protocol (the transports do that before they call it, with the
// rules of stream_request.h); it enforces capacity (RESOURCE_EXHAUSTED "server at capacity: N of N
// sessions"), refuses during drain (UNAVAILABLE), opens the engine stream (INVALID_ARGUMENT for configs the
// engine refuses) and hands the session to the least loaded scheduler. Sessions leave the registry when their scheduler completes them.
//
// Usage:
//   SessionHub hub(backend.get(), HubOptions{.max_sessions = 200}, &metrics);
//   ASSIGN_OR_RETURN(std::shared_ptr<LiveSession> s, hub.Admit(config, PcmFormat::kF32Le, "cli"));
//   hub.Find(id)->AddViewer(sink);
//   hub.StartDrain(); hub.WaitUntilEmpty(absl::Seconds(30)); hub.Shutdown();
//
// Thread safety: every public method is thread-safe.
#ifndef DANCE_SERVER_CORE_SESSION_HUB_H_
#define DANCE_SERVER_CORE_SESSION_HUB_H_

#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "absl/base/thread_annotations.h"
#include "absl/container/flat_hash_map.h"
#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"
#include "server/core/engine_port.h"
#include "server/core/live_session.h"
#include "server/core/metrics.h"
#include "server/core/scheduler.h"
#include "server/core/stream_request.h"

namespace dance::server {

struct HubOptions {
  int max_sessions = 256;
  int scheduler_threads = 1;
  int max_batch = 256;
  int64_t max_pending_samples = 48000 * 10;  // per session inbox, input sample frames
  int max_viewers_per_session = 64;
  absl::Duration idle_timeout = absl::Seconds(30);
  absl::Duration max_duration = absl::Hours(4);
  size_t output_soft_limit = 64;                     // see SessionSettings
  absl::Duration stall_timeout = absl::Seconds(10);  // see SessionSettings
};

class SessionHub {
 public:
  SessionHub(const EngineBackend* backend, HubOptions options, ServerMetrics* metrics);
  ~SessionHub();  // Shutdown()
  SessionHub(const SessionHub&) = delete;
  SessionHub& operator=(const SessionHub&) = delete;

  absl::StatusOr<std::shared_ptr<LiveSession>> Admit(const StreamConfig& config, PcmFormat format,
                                                     std::string client_name);
  // nullptr if no live session has this id.
  std::shared_ptr<LiveSession> Find(absl::string_view id) const;
  std::vector<SessionSummary> List() const;  // newest first
  int active_sessions() const;
  const ModelDescription& model() const { return backend_->Describe(); }
  const HubOptions& options() const { return options_; }

  // Serving = not draining and below capacity. The listener runs whenever that may have changed (from
  // Admit's caller or a scheduler thread); it must be cheap and thread-safe.
  void SetServingListener(std::function<void(bool serving)> listener);
  bool serving() const;
  void StartDrain();
  bool draining() const;
  // True if every session ended before the timeout.
  bool WaitUntilEmpty(absl::Duration timeout);
  // Stops the schedulers; sessions still live end with UNAVAILABLE. Idempotent.
  void Shutdown();

 private:
  void OnComplete(LiveSession& session, const absl::Status& status);
  void NotifyServing();

  const EngineBackend* const backend_;
  const HubOptions options_;
  ServerMetrics* const metrics_;
  std::vector<std::unique_ptr<Scheduler>> schedulers_;

  mutable absl::Mutex mu_;
  absl::flat_hash_map<std::string, std::shared_ptr<LiveSession>> sessions_ ABSL_GUARDED_BY(mu_);
  int reserved_ ABSL_GUARDED_BY(mu_) = 0;  // admissions in progress (engine stream being opened)
  bool draining_ ABSL_GUARDED_BY(mu_) = false;
  bool shut_down_ ABSL_GUARDED_BY(mu_) = false;
  std::function<void(bool)> listener_ ABSL_GUARDED_BY(mu_);
};

}  // namespace dance::server

#endif  // DANCE_SERVER_CORE_SESSION_HUB_H_
