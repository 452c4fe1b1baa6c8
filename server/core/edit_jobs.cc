#include "server/core/edit_jobs.h"

#include <algorithm>
#include <cmath>
#include <chrono>
#include <utility>

#include "absl/strings/str_cat.h"
#include "server/core/stream_request.h"

namespace dance::server {

absl::Status ValidateEditConfig(const EditConfig& c, const EditorDescription& editor) {
  if (c.audio.empty()) return absl::InvalidArgumentError("audio: no song given");
  if (c.steps < 0 || c.steps > 1000) {
    return absl::InvalidArgumentError(absl::StrCat("steps: must be 0 (the model's default) to 1000, got ", c.steps));
  }
  if (!(c.guidance >= 0.0f && c.guidance <= 100.0f)) {
    return absl::InvalidArgumentError(absl::StrCat("guidance: must be 0 (the model's default) to 100, got ",
                                                   c.guidance));
  }
  if (!(c.overlap_s >= 0.0 && c.overlap_s < editor.window_s)) {
    return absl::InvalidArgumentError(absl::StrCat("overlap_s: must be in [0, ", editor.window_s, "), got ",
                                                   c.overlap_s));
  }
  for (const auto& [name, weight] : c.style) {
    if (!(weight >= 0.0f) || !std::isfinite(weight)) {
      return absl::InvalidArgumentError(absl::StrCat("style '", name, "': weight must be finite and >= 0"));
    }
  }
  return ValidateControlSpec(c.controls);
}

EditJobs::EditJobs(const EditorBackend* editor, EditJobsOptions options) : editor_(editor), options_(options) {
  for (int i = 0; i < std::max(1, options_.workers); ++i) workers_.emplace_back([this] { Work(); });
}

EditJobs::~EditJobs() { Shutdown(); }

absl::StatusOr<std::shared_ptr<EditJob>> EditJobs::Submit(std::string client, EditConfig config,
                                                         std::function<void(const EditEvent&)> listener) {
  auto job = std::make_shared<EditJob>();
  job->client = std::move(client);
  job->config = std::move(config);
  job->listener = std::move(listener);
  int position = 0;
  {
    absl::MutexLock lock(&mu_);
    if (stopping_) return absl::UnavailableError("the server is shutting down");
    int& mine = per_client_[job->client];
    if (mine >= options_.max_per_client) {
      if (mine == 0) per_client_.erase(job->client);
      return absl::ResourceExhaustedError(absl::StrCat("this client already has ", mine,
                                                       " edit(s) queued or running (the limit is ",
                                                       options_.max_per_client, ")"));
    }
    const int idle = std::max(1, options_.workers) - running_;
    if (static_cast<int>(queue_.size()) >= options_.max_queued + std::max(0, idle)) {
      if (mine == 0) per_client_.erase(job->client);
      return absl::ResourceExhaustedError(absl::StrCat("the edit queue is full (", queue_.size(), " waiting)"));
    }
    ++mine;
    position = static_cast<int>(queue_.size());
    queue_.push_back(job);
  }
  EditEvent e;
  e.kind = EditEvent::Kind::kQueued;
  e.position = position;
  job->listener(e);
  return job;
}

void EditJobs::Shutdown() {
  std::deque<std::shared_ptr<EditJob>> left;
  {
    absl::MutexLock lock(&mu_);
    if (stopping_ && workers_.empty()) return;
    stopping_ = true;
    left.swap(queue_);
  }
  for (const auto& job : left) {
    job->Cancel();
    EditEvent e;
    e.kind = EditEvent::Kind::kDone;
    e.status = absl::UnavailableError("the server is shutting down");
    job->listener(e);
  }
  for (std::thread& t : workers_) t.join();
  workers_.clear();
}

int EditJobs::running() const {
  absl::MutexLock lock(&mu_);
  return running_;
}

int EditJobs::queued() const {
  absl::MutexLock lock(&mu_);
  return static_cast<int>(queue_.size());
}

void EditJobs::Finish(const std::shared_ptr<EditJob>& job) {
  absl::MutexLock lock(&mu_);
  --running_;
  auto it = per_client_.find(job->client);
  if (it != per_client_.end() && --it->second <= 0) per_client_.erase(it);
}

void EditJobs::Work() {
  for (;;) {
    std::shared_ptr<EditJob> job;
    std::vector<std::shared_ptr<EditJob>> waiting;
    {
      absl::MutexLock lock(&mu_);
      mu_.Await(absl::Condition(
          +[](EditJobs* self) ABSL_EXCLUSIVE_LOCKS_REQUIRED(self->mu_) {
            return self->stopping_ || !self->queue_.empty();
          },
          this));
      if (queue_.empty()) return;  // stopping
      job = queue_.front();
      queue_.pop_front();
      ++running_;
      waiting.assign(queue_.begin(), queue_.end());
    }
    // The jobs behind it moved up one place.
    for (size_t i = 0; i < waiting.size(); ++i) {
      EditEvent e;
      e.kind = EditEvent::Kind::kQueued;
      e.position = static_cast<int>(i);
      waiting[i]->listener(e);
    }
    EditEvent done;
    done.kind = EditEvent::Kind::kDone;
    if (job->cancelled()) {
      done.status = absl::CancelledError("the edit was cancelled");
    } else {
      const auto start = std::chrono::steady_clock::now();
      absl::StatusOr<EditOutput> out =
          editor_->Edit(job->config, options_.max_audio_s, [&job](const EditProgress& p) {
            if (job->cancelled()) return false;
            EditEvent e;
            e.kind = EditEvent::Kind::kProgress;
            e.progress = p;
            job->listener(e);
            return true;
          });
      done.compute_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      if (out.ok()) {
        done.output = std::make_shared<EditOutput>(*std::move(out));
      } else {
        done.status = out.status();
      }
    }
    Finish(job);
    job->listener(done);
  }
}

}  // namespace dance::server
