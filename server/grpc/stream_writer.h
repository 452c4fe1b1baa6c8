// StreamWriter: the FrameSink of one gRPC streaming call. It serialises every operation on the call
// (write, read, finish) so that the callback API's rules hold however many threads deliver updates:
//   - at most one write in flight; updates wait in a queue;
//   - Finish is issued exactly once, never while a write is in flight or another thread is issuing an op;
//   - no op is issued after Finish (so the reactor outlives every op issued through this writer).
// No lock is held while calling into gRPC (reactions may run inline).
//
// Lossless mode (performers): the queue may hold `limit` updates; beyond that the call finishes with
// RESOURCE_EXHAUSTED (the client stopped reading). A performer's call that ends OK finishes only once the
// client has half-closed (ReadsDone) or `half_close_grace` has passed since Close(OK): until then a message
// the client sends after EndOfAudio can still turn the status into its protocol error (Abort), so "audio
// after EndOfAudio" is INVALID_ARGUMENT however fast the session completed. Lossy mode (viewers): at most `limit` frames are queued;
// the oldest queued frame is dropped for a new one and the next frame sent carries dropped_before.
//
// Encoding: the writer sends each core update as its DanceUpdate (convert.h's UpdateToProto, with or
// without rotations), encoded in Deliver on the delivering thread (for frames, the scheduler thread)
// and shared with every other gRPC call that sends the same update; only a frame that carries
// dropped_before is copied, for its one viewer.
//
// R must provide: void IssueWrite(const dance::v1::DanceUpdate*); void IssueRead(); void IssueFinish(grpc::Status).
// Thread safety: all methods are thread-safe.
#ifndef DANCE_SERVER_GRPC_STREAM_WRITER_H_
#define DANCE_SERVER_GRPC_STREAM_WRITER_H_

#include <atomic>
#include <cstddef>
#include <deque>
#include <memory>
#include <optional>
#include <utility>

#include <grpcpp/alarm.h>
#include <grpcpp/grpcpp.h>

#include "absl/base/thread_annotations.h"
#include "absl/status/status.h"
#include "absl/strings/str_cat.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/clock.h"
#include "absl/time/time.h"
#include "dance/v1/dance.pb.h"
#include "server/core/frame_sink.h"
#include "server/core/metrics.h"
#include "server/grpc/convert.h"

namespace dance::server {

inline grpc::Status ToGrpcStatus(const absl::Status& s) {
  return grpc::Status(static_cast<grpc::StatusCode>(s.code()), std::string(s.message()));
}

template <typename R>
class StreamWriter : public FrameSink, public std::enable_shared_from_this<StreamWriter<R>> {
 public:
  enum class Mode { kLossless, kLossy };

  StreamWriter(R* reactor, Mode mode, size_t limit, bool wants_rotations, ServerMetrics* metrics)
      : reactor_(reactor), mode_(mode), limit_(limit), wants_rotations_(wants_rotations), metrics_(metrics) {}

  void Deliver(const UpdatePtr& update) override {
    // Encoded here, before the lock: the first writer of the session to see an update builds its message,
    // the others find it built; the write path below only reads it.
    UpdateToProto(*update, WantsRotations());
    const dance::v1::DanceUpdate* write = nullptr;
    bool finish = false;
    {
      absl::MutexLock lock(&mu_);
      if (finish_issued_ || closing_) return;
      if (mode_ == Mode::kLossy && update->is_frame() && queued_frames_ >= limit_) {
        for (auto it = queue_.begin(); it != queue_.end(); ++it) {
          if ((*it)->is_frame()) {
            queue_.erase(it);
            --queued_frames_;
            ++dropped_pending_;
            metrics_->viewer_frames_dropped_total.fetch_add(1, std::memory_order_relaxed);
            break;
          }
        }
      } else if (mode_ == Mode::kLossless && queue_.size() >= limit_) {
        closing_ = true;
        close_status_ = absl::ResourceExhaustedError(
            absl::StrCat("client is not reading: ", queue_.size(), " updates queued"));
        queue_.clear();
        queued_frames_ = 0;
        finish = ShouldFinishLocked();
      }
      if (!closing_) {
        queue_.push_back(update);
        if (update->is_frame()) ++queued_frames_;
        write = StartNextLocked();
      }
    }
    if (write != nullptr) IssueWriteAndExit(write);
    if (finish) reactor_->IssueFinish(ToGrpcStatus(close_status_copy()));
  }

  void Close(const absl::Status& status) override {
    bool finish = false;
    bool arm = false;
    {
      absl::MutexLock lock(&mu_);
      if (closing_ || finish_issued_) return;
      closing_ = true;
      close_status_ = status;
      if (!status.ok()) {
        queue_.clear();
        queued_frames_ = 0;
      }
      finish = ShouldFinishLocked();
      arm = status.ok() && !finish && !reads_done_ && half_close_grace_ > absl::ZeroDuration();
    }
    if (finish) reactor_->IssueFinish(ToGrpcStatus(close_status_copy()));
    if (arm) ArmHalfCloseGrace();
  }

  // Requires the client's half-close before an OK finish (performers; call before the writer is shared).
  // After `grace` without one the call finishes OK anyway (a client that never half-closes).
  void RequireHalfCloseBeforeOk(absl::Duration grace) {
    absl::MutexLock lock(&mu_);
    reads_done_ = false;
    half_close_grace_ = grace;
  }

  // The client half-closed (or the read side is over): an OK finish no longer waits for it.
  void ReadsDone() {
    bool finish = false;
    {
      absl::MutexLock lock(&mu_);
      if (reads_done_) return;
      reads_done_ = true;
      finish = ShouldFinishLocked();
    }
    if (finish) reactor_->IssueFinish(ToGrpcStatus(close_status_copy()));
  }

  // An error seen after the session already ended (LiveSession::Fail refused it: audio after EndOfAudio,
  // a cancel): unless the call already finishes with an error or its finish was issued, finish with
  // `status` instead of OK (even if the session's Close(OK) has not arrived yet; it is then ignored) and
  // count it in dance_errors_total (the session was counted as OK). Returns whether it applied.
  bool Abort(const absl::Status& status) {
    bool finish = false;
    {
      absl::MutexLock lock(&mu_);
      if (finish_issued_ || (closing_ && !close_status_.ok())) return false;
      closing_ = true;
      metrics_->CountError(status.code());
      close_status_ = status.ok() ? absl::InternalError("Abort(OK)") : status;
      queue_.clear();
      queued_frames_ = 0;
      finish = ShouldFinishLocked();
    }
    if (finish) reactor_->IssueFinish(ToGrpcStatus(close_status_copy()));
    return true;
  }

  bool WantsRotations() const { return wants_rotations_.load(std::memory_order_relaxed); }
  // Set before the writer is attached to a session.
  void SetWantsRotations(bool wants) { wants_rotations_.store(wants, std::memory_order_relaxed); }

  size_t Backlog() const override {
    absl::MutexLock lock(&mu_);
    return queue_.size();
  }

  // The reactor's OnWriteDone.
  void OnWriteDone(bool ok) {
    const dance::v1::DanceUpdate* write = nullptr;
    bool finish = false;
    {
      absl::MutexLock lock(&mu_);
      writing_ = false;
      current_.reset();
      current_copy_.reset();
      if (!ok && (!closing_ || close_status_.ok())) {
        // The client is gone. Even if the session already ended OK, the call did not: it never got the
        // rest of its updates (an OK close is replaced and counted here; otherwise the session counts it).
        if (closing_) metrics_->CountError(absl::StatusCode::kCancelled);
        closing_ = true;
        close_status_ = absl::CancelledError("write failed: the client went away");
        queue_.clear();
        queued_frames_ = 0;
      }
      if (!closing_ || close_status_.ok()) write = StartNextLocked();
      if (write == nullptr) finish = ShouldFinishLocked();
    }
    if (write != nullptr) IssueWriteAndExit(write);
    if (finish) reactor_->IssueFinish(ToGrpcStatus(close_status_copy()));
  }

  // Issues a read on the call unless it is finished (reactor thread, or the session's read resumer).
  void Read() {
    {
      absl::MutexLock lock(&mu_);
      if (finish_issued_) return;
      ++in_call_;
    }
    reactor_->IssueRead();
    ExitCall();
  }

  bool closing() const {
    absl::MutexLock lock(&mu_);
    return closing_ || finish_issued_;
  }

 private:
  const dance::v1::DanceUpdate* StartNextLocked() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_) {
    if (writing_ || queue_.empty() || finish_issued_) return nullptr;
    current_ = std::move(queue_.front());
    queue_.pop_front();
    const dance::v1::DanceUpdate* write = &UpdateToProto(*current_, WantsRotations());
    if (current_->is_frame()) {
      --queued_frames_;
      if (dropped_pending_ > 0) {
        current_copy_ = std::make_unique<dance::v1::DanceUpdate>(*write);
        current_copy_->mutable_frame()->set_dropped_before(dropped_pending_);
        dropped_pending_ = 0;
        write = current_copy_.get();
      }
    }
    writing_ = true;
    ++in_call_;
    return write;
  }

  bool ShouldFinishLocked() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_) {
    if (!closing_ || writing_ || in_call_ > 0 || finish_issued_) return false;
    if (close_status_.ok() && (!queue_.empty() || !reads_done_)) return false;
    finish_issued_ = true;
    return true;
  }

  void IssueWriteAndExit(const dance::v1::DanceUpdate* write) {
    reactor_->IssueWrite(write);
    ExitCall();
  }

  void ExitCall() {
    bool finish = false;
    {
      absl::MutexLock lock(&mu_);
      --in_call_;
      finish = ShouldFinishLocked();
    }
    if (finish) reactor_->IssueFinish(ToGrpcStatus(close_status_copy()));
  }

  // The alarm's callback holds only a weak reference: a writer destroyed first cancels it harmlessly.
  void ArmHalfCloseGrace() {
    std::weak_ptr<StreamWriter> weak = this->weak_from_this();
    absl::MutexLock lock(&mu_);
    if (finish_issued_ || grace_alarm_ != nullptr) return;
    grace_alarm_ = std::make_unique<grpc::Alarm>();
    grace_alarm_->Set(absl::ToChronoTime(absl::Now() + half_close_grace_), [weak](bool fired) {
      if (!fired) return;
      if (auto w = weak.lock()) w->ReadsDone();
    });
  }

  absl::Status close_status_copy() const {
    absl::MutexLock lock(&mu_);
    return close_status_;
  }

  R* const reactor_;
  const Mode mode_;
  const size_t limit_;
  std::atomic<bool> wants_rotations_;
  ServerMetrics* const metrics_;

  mutable absl::Mutex mu_;
  std::deque<UpdatePtr> queue_ ABSL_GUARDED_BY(mu_);
  size_t queued_frames_ ABSL_GUARDED_BY(mu_) = 0;
  int64_t dropped_pending_ ABSL_GUARDED_BY(mu_) = 0;
  UpdatePtr current_ ABSL_GUARDED_BY(mu_);  // the update being written (it owns the shared message)
  std::unique_ptr<dance::v1::DanceUpdate> current_copy_ ABSL_GUARDED_BY(mu_);  // its copy with dropped_before
  bool writing_ ABSL_GUARDED_BY(mu_) = false;
  int in_call_ ABSL_GUARDED_BY(mu_) = 0;
  bool closing_ ABSL_GUARDED_BY(mu_) = false;
  bool finish_issued_ ABSL_GUARDED_BY(mu_) = false;
  absl::Status close_status_ ABSL_GUARDED_BY(mu_);
  bool reads_done_ ABSL_GUARDED_BY(mu_) = true;  // false until ReadsDone() for RequireHalfCloseBeforeOk
  absl::Duration half_close_grace_ ABSL_GUARDED_BY(mu_) = absl::ZeroDuration();
  std::unique_ptr<grpc::Alarm> grace_alarm_ ABSL_GUARDED_BY(mu_);
};

}  // namespace dance::server

#endif  // DANCE_SERVER_GRPC_STREAM_WRITER_H_
