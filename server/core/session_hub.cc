#include "server/core/session_hub.h"

#include <algorithm>
#include <utility>

#include "absl/random/random.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "server/log.h"

namespace dance::server {
namespace {

std::string NewSessionId() {
  static absl::Mutex mu(absl::kConstInit);
  static absl::BitGen* gen = new absl::BitGen();
  absl::MutexLock lock(&mu);
  return absl::StrFormat("s-%016x", absl::Uniform<uint64_t>(*gen));
}

}  // namespace

SessionHub::SessionHub(const EngineBackend* backend, HubOptions options, ServerMetrics* metrics)
    : backend_(backend), options_(options), metrics_(metrics) {
  const int n = std::max(1, options_.scheduler_threads);
  for (int i = 0; i < n; ++i) {
    schedulers_.push_back(std::make_unique<Scheduler>(
        backend_, metrics_, SchedulerOptions{.max_batch = options_.max_batch},
        [this](LiveSession& s, const absl::Status& st) { OnComplete(s, st); }));
  }
  for (auto& s : schedulers_) s->Start();
}

SessionHub::~SessionHub() { Shutdown(); }

absl::StatusOr<std::shared_ptr<LiveSession>> SessionHub::Admit(const StreamConfig& config, PcmFormat format,
                                                               std::string client_name) {
  {
    absl::MutexLock lock(&mu_);
    if (draining_ || shut_down_) {
      metrics_->sessions_rejected_total.fetch_add(1);
      return absl::UnavailableError("server is draining; connect to another instance");
    }
    const int used = static_cast<int>(sessions_.size()) + reserved_;
    if (used >= options_.max_sessions) {
      metrics_->sessions_rejected_total.fetch_add(1);
      return absl::ResourceExhaustedError(absl::StrCat("server at capacity: ", used, " of ",
                                                       options_.max_sessions, " sessions; retry later"));
    }
    ++reserved_;
  }
  absl::StatusOr<std::unique_ptr<EngineStream>> stream = backend_->Open(config);
  if (!stream.ok()) {
    absl::MutexLock lock(&mu_);
    --reserved_;
    return stream.status();
  }
  Scheduler* sched = schedulers_.front().get();
  for (auto& s : schedulers_) {
    if (s->size() < sched->size()) sched = s.get();
  }
  SessionSettings settings;
  settings.id = NewSessionId();
  settings.client_name = std::move(client_name);
  settings.config = config;
  settings.format = format;
  settings.max_pending_samples = options_.max_pending_samples;
  settings.max_viewers = options_.max_viewers_per_session;
  settings.idle_timeout = options_.idle_timeout;
  settings.max_duration = options_.max_duration;
  settings.output_soft_limit = options_.output_soft_limit;
  settings.stall_timeout = options_.stall_timeout;
  settings.wake = [sched] { sched->Wake(); };
  auto session = std::make_shared<LiveSession>(std::move(settings), *std::move(stream), backend_->Describe(),
                                               metrics_, absl::Now());
  {
    absl::MutexLock lock(&mu_);
    --reserved_;
    sessions_[session->id()] = session;
  }
  metrics_->sessions_started_total.fetch_add(1);
  Log(LogLevel::kInfo, "session_start",
      {{"session", session->id()}, {"client", session->settings().client_name},
       {"sample_rate", config.sample_rate_hz}, {"channels", config.channels}, {"seed", config.seed}});
  sched->Add(session);
  NotifyServing();
  return session;
}

std::shared_ptr<LiveSession> SessionHub::Find(absl::string_view id) const {
  absl::MutexLock lock(&mu_);
  auto it = sessions_.find(id);
  return it == sessions_.end() ? nullptr : it->second;
}

std::vector<SessionSummary> SessionHub::List() const {
  std::vector<std::shared_ptr<LiveSession>> live;
  {
    absl::MutexLock lock(&mu_);
    for (const auto& [id, s] : sessions_) live.push_back(s);
  }
  std::vector<SessionSummary> out;
  out.reserve(live.size());
  for (const auto& s : live) out.push_back(s->Summary());
  std::sort(out.begin(), out.end(), [](const SessionSummary& a, const SessionSummary& b) {
    return a.started_unix_ms != b.started_unix_ms ? a.started_unix_ms > b.started_unix_ms
                                                  : a.session_id < b.session_id;
  });
  return out;
}

int SessionHub::active_sessions() const {
  absl::MutexLock lock(&mu_);
  return static_cast<int>(sessions_.size());
}

void SessionHub::SetServingListener(std::function<void(bool)> listener) {
  {
    absl::MutexLock lock(&mu_);
    listener_ = std::move(listener);
  }
  NotifyServing();
}

bool SessionHub::serving() const {
  absl::MutexLock lock(&mu_);
  return !draining_ && !shut_down_ && static_cast<int>(sessions_.size()) + reserved_ < options_.max_sessions;
}

void SessionHub::NotifyServing() {
  std::function<void(bool)> listener;
  {
    absl::MutexLock lock(&mu_);
    listener = listener_;
  }
  if (listener) listener(serving());
}

void SessionHub::StartDrain() {
  {
    absl::MutexLock lock(&mu_);
    draining_ = true;
  }
  Log(LogLevel::kInfo, "drain_start", {{"sessions", active_sessions()}});
  NotifyServing();
}

bool SessionHub::draining() const {
  absl::MutexLock lock(&mu_);
  return draining_;
}

bool SessionHub::WaitUntilEmpty(absl::Duration timeout) {
  absl::MutexLock lock(&mu_);
  auto empty = [this]() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_) { return sessions_.empty() && reserved_ == 0; };
  return mu_.AwaitWithTimeout(absl::Condition(&empty), timeout);
}

void SessionHub::Shutdown() {
  {
    absl::MutexLock lock(&mu_);
    if (shut_down_) return;
    shut_down_ = true;
  }
  for (auto& s : schedulers_) s->Stop();
}

void SessionHub::OnComplete(LiveSession& session, const absl::Status& status) {
  // Counted before the session leaves the registry: whoever sees active_sessions() drop sees the counts.
  metrics_->sessions_finished_total.fetch_add(1);
  if (!status.ok()) metrics_->CountError(status.code());
  {
    absl::MutexLock lock(&mu_);
    sessions_.erase(session.id());
  }
  const SessionSummary sum = session.Summary();
  Log(status.ok() ? LogLevel::kInfo : LogLevel::kWarning, "session_end",
      {{"session", session.id()}, {"status", absl::StatusCodeToString(status.code())},
       {"message", status.message()}, {"frames", sum.frames}, {"audio_ms", sum.audio_ms}});
  NotifyServing();
}

}  // namespace dance::server
