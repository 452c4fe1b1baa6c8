// FrameSink: where a live session's updates (info, frames, events, end) go. One per performer and one per
// viewer; implemented by the transports (server/grpc/stream_writer.h for gRPC calls, server/web/ws_sink.h
// for WebSockets), each of which encodes the updates into its own wire form.
//
// Thread safety: implementations must make Deliver and Close safe to call from any thread, and must never
// block in them (the scheduler thread calls them between engine steps).
#ifndef DANCE_SERVER_CORE_FRAME_SINK_H_
#define DANCE_SERVER_CORE_FRAME_SINK_H_

#include <cstddef>

#include "absl/status/status.h"
#include "server/core/update.h"

namespace dance::server {

class FrameSink {
 public:
  virtual ~FrameSink() = default;
  // Queues one update (shared with the session's other sinks; never modified). A performer sink never
  // drops frames (it fails its call when its queue overflows); a viewer sink drops its oldest queued
  // frames instead.
  virtual void Deliver(const UpdatePtr& update) = 0;
  // The session is over. OK: the StreamEnd update was already delivered; flush and finish. Error: finish
  // with that status as soon as possible (queued updates may be discarded). Called at most once per sink
  // by the session, but implementations must tolerate repeats.
  virtual void Close(const absl::Status& status) = 0;
  // Updates queued and not yet handed to the transport (the scheduler stops stepping a session whose
  // performer backlog is high, so a fast client is paced by its own reading speed).
  virtual size_t Backlog() const = 0;
};

}  // namespace dance::server

#endif  // DANCE_SERVER_CORE_FRAME_SINK_H_
