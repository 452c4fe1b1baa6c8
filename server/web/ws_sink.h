// WsSink: the FrameSink of one WebSocket connection. The scheduler Delivers without blocking; the
// connection's writer thread takes updates with Next() and sends them as JSON text messages
// (json_codec.h's UpdateToJson, so the text of an update is built once for every socket that sends it).
//
// Lossy (viewers): at most `limit` frames queued, the oldest dropped first (counted in dropped_before of the
// next frame sent). Lossless (performers): over `limit` queued updates the sink closes itself with
// RESOURCE_EXHAUSTED.
// Thread safety: all methods are thread-safe.
#ifndef DANCE_SERVER_WEB_WS_SINK_H_
#define DANCE_SERVER_WEB_WS_SINK_H_

#include <cstddef>
#include <cstdint>
#include <deque>

#include "absl/base/thread_annotations.h"
#include "absl/status/status.h"
#include "absl/synchronization/mutex.h"
#include "server/core/frame_sink.h"
#include "server/core/metrics.h"
#include "server/core/update.h"

namespace dance::server {

class WsSink : public FrameSink {
 public:
  WsSink(bool lossy, size_t limit, bool wants_rotations, ServerMetrics* metrics)
      : lossy_(lossy), limit_(limit), wants_rotations_(wants_rotations), metrics_(metrics) {}

  void Deliver(const UpdatePtr& update) override;
  void Close(const absl::Status& status) override;
  size_t Backlog() const override;
  // Whether frames are sent with their rotations.
  bool wants_rotations() const { return wants_rotations_; }

  // Blocks until an update is ready (true; *dropped_before = frames dropped just before it, 0 for
  // anything but a frame) or the sink is closed and drained (false, *final = the status).
  bool Next(UpdatePtr* update, int64_t* dropped_before, absl::Status* final);

 private:
  const bool lossy_;
  const size_t limit_;
  const bool wants_rotations_;
  ServerMetrics* const metrics_;

  mutable absl::Mutex mu_;
  std::deque<UpdatePtr> queue_ ABSL_GUARDED_BY(mu_);
  size_t frames_ ABSL_GUARDED_BY(mu_) = 0;
  int64_t dropped_ ABSL_GUARDED_BY(mu_) = 0;
  bool closed_ ABSL_GUARDED_BY(mu_) = false;
  absl::Status status_ ABSL_GUARDED_BY(mu_);
};

}  // namespace dance::server

#endif  // DANCE_SERVER_WEB_WS_SINK_H_
