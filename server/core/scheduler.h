// Scheduler: one thread that owns a set of LiveSessions and advances every due session in batched engine
// steps (one EngineBackend::StepBatch pass over the weights serves many sessions).
//
// Each pass: take new sessions, check health (failures, timeouts), drain inboxes into the engine, then one
// step round: every session with a ready step takes exactly one step (so a client streaming as fast as
// possible cannot starve real-time ones). Passes follow each other without waiting while steps were taken,
// so new sessions, fresh audio and timeouts are handled between rounds even when the engine is behind.
// Finished sessions are completed, handed to `on_complete`, and only then their sinks are closed.
//
// Usage:
//   Scheduler sched(backend, &metrics, {.max_batch = 256}, [](LiveSession& s, const absl::Status& st) {...});
//   sched.Start();  sched.Add(session);  ...  sched.Stop();   // Stop completes leftovers with UNAVAILABLE
//
// Thread safety: Add, Wake, size and Stop may be called from any thread. on_complete runs on the
// scheduler thread.
#ifndef DANCE_SERVER_CORE_SCHEDULER_H_
#define DANCE_SERVER_CORE_SCHEDULER_H_

#include <atomic>
#include <functional>
#include <memory>
#include <thread>
#include <vector>

#include "absl/base/thread_annotations.h"
#include "absl/status/status.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"
#include "server/core/engine_port.h"
#include "server/core/live_session.h"
#include "server/core/metrics.h"

namespace dance::server {

struct SchedulerOptions {
  int max_batch = 256;                             // sessions per StepBatch call
  absl::Duration poll = absl::Milliseconds(20);    // wake-up period for timeouts when idle
};

class Scheduler {
 public:
  using CompletionFn = std::function<void(LiveSession& session, const absl::Status& status)>;

  Scheduler(const EngineBackend* backend, ServerMetrics* metrics, SchedulerOptions options,
            CompletionFn on_complete);
  ~Scheduler();  // calls Stop()
  Scheduler(const Scheduler&) = delete;
  Scheduler& operator=(const Scheduler&) = delete;

  void Start();
  // Ends every remaining session with UNAVAILABLE and joins the thread. Idempotent.
  void Stop();
  void Add(std::shared_ptr<LiveSession> session);
  void Wake();
  // Sessions owned (including ones not yet picked up).
  int size() const { return size_.load(std::memory_order_relaxed); }

 private:
  void Run();
  // Health, drain, one step round, completions. Returns whether any session stepped (more may be ready).
  bool Pass();
  void CompleteSession(LiveSession& session, const absl::Status& status);

  const EngineBackend* const backend_;
  ServerMetrics* const metrics_;
  const SchedulerOptions options_;
  const CompletionFn on_complete_;

  absl::Mutex mu_;
  std::vector<std::shared_ptr<LiveSession>> incoming_ ABSL_GUARDED_BY(mu_);
  bool wake_ ABSL_GUARDED_BY(mu_) = false;
  bool stop_ ABSL_GUARDED_BY(mu_) = false;
  std::atomic<int> size_{0};
  std::thread thread_;

  // Scheduler-thread state.
  std::vector<std::shared_ptr<LiveSession>> sessions_;
  std::vector<LiveSession*> batch_;
  std::vector<EngineStream*> streams_;
};

}  // namespace dance::server

#endif  // DANCE_SERVER_CORE_SCHEDULER_H_
