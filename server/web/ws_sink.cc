#include "server/web/ws_sink.h"

#include <utility>

#include "absl/strings/str_cat.h"

namespace dance::server {

void WsSink::Deliver(const UpdatePtr& update) {
  absl::MutexLock lock(&mu_);
  if (closed_) return;
  if (lossy_ && update->is_frame() && frames_ >= limit_) {
    for (auto it = queue_.begin(); it != queue_.end(); ++it) {
      if ((*it)->is_frame()) {
        queue_.erase(it);
        --frames_;
        ++dropped_;
        metrics_->viewer_frames_dropped_total.fetch_add(1, std::memory_order_relaxed);
        break;
      }
    }
  } else if (!lossy_ && queue_.size() >= limit_) {
    closed_ = true;
    status_ = absl::ResourceExhaustedError(absl::StrCat("client is not reading: ", queue_.size(), " queued"));
    queue_.clear();
    frames_ = 0;
    return;
  }
  queue_.push_back(update);
  if (update->is_frame()) ++frames_;
}

void WsSink::Close(const absl::Status& status) {
  absl::MutexLock lock(&mu_);
  if (closed_) return;
  closed_ = true;
  status_ = status;
  if (!status.ok()) {
    queue_.clear();
    frames_ = 0;
  }
}

size_t WsSink::Backlog() const {
  absl::MutexLock lock(&mu_);
  return queue_.size();
}

bool WsSink::Next(UpdatePtr* update, int64_t* dropped_before, absl::Status* final) {
  absl::MutexLock lock(&mu_);
  auto ready = [this]() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_) { return !queue_.empty() || closed_; };
  mu_.Await(absl::Condition(&ready));
  if (queue_.empty()) {
    *final = status_;
    return false;
  }
  *update = std::move(queue_.front());
  queue_.pop_front();
  *dropped_before = 0;
  if ((*update)->is_frame()) {
    --frames_;
    *dropped_before = dropped_;
    dropped_ = 0;
  }
  return true;
}

}  // namespace dance::server
