#include "server/core/scheduler.h"

#include <algorithm>
#include <utility>

namespace dance::server {

Scheduler::Scheduler(const EngineBackend* backend, ServerMetrics* metrics, SchedulerOptions options,
                     CompletionFn on_complete)
    : backend_(backend), metrics_(metrics), options_(options), on_complete_(std::move(on_complete)) {}

Scheduler::~Scheduler() { Stop(); }

void Scheduler::Start() { thread_ = std::thread([this] { Run(); }); }

void Scheduler::Stop() {
  {
    absl::MutexLock lock(&mu_);
    stop_ = true;
  }
  if (thread_.joinable()) thread_.join();
  // Whatever is left (thread stopped, or never started) ends here, on the caller's thread.
  std::vector<std::shared_ptr<LiveSession>> left;
  {
    absl::MutexLock lock(&mu_);
    left.swap(incoming_);
  }
  for (auto& s : sessions_) left.push_back(std::move(s));
  sessions_.clear();
  for (auto& s : left) CompleteSession(*s, absl::UnavailableError("server shutting down"));
}

void Scheduler::Add(std::shared_ptr<LiveSession> session) {
  size_.fetch_add(1, std::memory_order_relaxed);
  absl::MutexLock lock(&mu_);
  incoming_.push_back(std::move(session));
  wake_ = true;
}

void Scheduler::Wake() {
  absl::MutexLock lock(&mu_);
  wake_ = true;
}

void Scheduler::CompleteSession(LiveSession& session, const absl::Status& status) {
  if (session.completed()) return;
  const absl::Status final_status = session.Complete(status);
  size_.fetch_sub(1, std::memory_order_relaxed);
  // Bookkeeping (registry, metrics) before the sinks close: whoever sees the call end sees it counted.
  on_complete_(session, final_status);
  session.CloseSinks();
}

void Scheduler::Run() {
  bool busy = false;
  while (true) {
    {
      absl::MutexLock lock(&mu_);
      auto due = [this]() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_) { return wake_ || stop_; };
      if (!busy) mu_.AwaitWithTimeout(absl::Condition(&due), options_.poll);
      if (stop_) return;
      wake_ = false;
      for (auto& s : incoming_) sessions_.push_back(std::move(s));
      incoming_.clear();
    }
    busy = Pass();
  }
}

bool Scheduler::Pass() {
  absl::Time now = absl::Now();
  for (auto& s : sessions_) {
    absl::Status st = s->CheckHealth(now);
    if (st.ok()) st = s->Drain(now);
    if (!st.ok()) CompleteSession(*s, st);
  }
  // One round: every ready session takes exactly one step (in batches of at most max_batch). The caller
  // runs the next pass at once, so new sessions, new audio and timeouts are seen between rounds even when
  // the engine cannot keep up (a pass never grows with the backlog).
  bool stepped = false;
  size_t next = 0;
  while (next < sessions_.size()) {
    batch_.clear();
    streams_.clear();
    for (; next < sessions_.size() && static_cast<int>(batch_.size()) < options_.max_batch; ++next) {
      LiveSession* s = sessions_[next].get();
      if (!s->ReadyToStep(now)) continue;
      batch_.push_back(s);
      streams_.push_back(s->engine_stream());
    }
    if (batch_.empty()) break;
    stepped = true;
    const absl::Time t0 = absl::Now();
    absl::Status st = backend_->StepBatch(streams_);
    now = absl::Now();
    metrics_->step_latency.Observe(absl::ToDoubleSeconds(now - t0));
    metrics_->batch_size.Observe(static_cast<double>(batch_.size()));
    metrics_->batches_total.fetch_add(1, std::memory_order_relaxed);
    metrics_->steps_total.fetch_add(batch_.size(), std::memory_order_relaxed);
    for (LiveSession* s : batch_) {
      if (st.ok()) {
        s->AfterStep(now);
      } else {
        CompleteSession(*s, st);
      }
    }
  }
  for (auto& s : sessions_) {
    if (!s->completed() && s->ReadyToComplete()) CompleteSession(*s, absl::OkStatus());
  }
  sessions_.erase(std::remove_if(sessions_.begin(), sessions_.end(),
                                 [](const std::shared_ptr<LiveSession>& s) { return s->completed(); }),
                  sessions_.end());
  return stepped;
}

}  // namespace dance::server
