// PerformStream: one Perform call driven by the gRPC callback API. It sends the header, then audio from a
// SampleSource in chunks (as the source makes them available: real time or as fast as possible), then
// EndOfAudio; it receives SessionInfo, frames and the end, and measures per-frame latency and skew.
//
// Latency of a frame = its arrival - the send time of the audio chunk that completed its step (the frame's
// trigger_sample_end names that chunk). Skew = (arrival - stream start) - frame.time_ms: how far the pose
// trails the audio's real-time position (meaningful in real-time mode).
//
// Usage:
//   PerformStream s(stub, std::move(source), options);
//   s.Start(absl::Now());
//   while (!s.done()) { s.Pump(absl::Now()); absl::SleepFor(absl::Milliseconds(5)); }   // a pacer thread
//   absl::Status st = s.Wait();
//
// Thread safety: Pump may be called from one pacer thread while gRPC runs the reactions; the accessors are
// safe after Wait() returns.
#ifndef DANCE_CLIENT_PERFORM_STREAM_H_
#define DANCE_CLIENT_PERFORM_STREAM_H_

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <grpcpp/grpcpp.h>

#include "absl/base/thread_annotations.h"
#include "absl/status/status.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"
#include "client/audio_source.h"
#include "client/controls_request.h"
#include "dance/v1/dance.grpc.pb.h"

namespace dance::client {

struct PerformOptions {
  dance::v1::StreamHeader header;   // sample rate/channels/format are filled from the source
  int chunk_ms = 40;                // audio per message
  bool keep_frames = true;          // keep every frame (for saving); load tests only count
  std::string auth_token;           // sent as "authorization: Bearer ..."
  // Controls sent mid-stream, each once the audio sent reaches its time (ascending at_s).
  std::vector<TimedControl> controls;
};

inline constexpr double kSlowFrameMs = 100.0;

struct FrameStats {
  int64_t frames = 0;
  int64_t gaps = 0;                 // frames missing from the index sequence
  std::vector<float> latency_ms;    // one per frame
  // Frames at least kSlowFrameMs late, to see when stalls happen (start of a stream, one moment for all
  // streams, ...) and where (before the frame left the server, or after).
  struct Slow {
    float at_s;        // arrival, seconds since the stream started
    float latency_ms;  // arrival - send of the triggering chunk
    float server_ms;   // the frame's server_time_us - that send (meaningful when client and server share a clock)
  };
  std::vector<Slow> slow;
  double max_skew_ms = 0.0;
};

class PerformStream : public grpc::ClientBidiReactor<dance::v1::PerformRequest, dance::v1::DanceUpdate> {
 public:
  PerformStream(dance::v1::DanceService::Stub* stub, std::unique_ptr<SampleSource> source, PerformOptions options);

  void Start(absl::Time t0);
  // Sends whatever audio is due (non-blocking).
  void Pump(absl::Time now);
  bool done() const;
  // Blocks until the call is over; returns its status.
  absl::Status Wait();
  // Frames received so far (thread-safe snapshot of the count).
  int64_t frames_received() const;
  // The session id once SessionInfo arrived, else empty (thread-safe).
  std::string session_id() const;

  const dance::v1::SessionInfo& info() const { return info_; }
  const std::vector<dance::v1::PoseFrame>& frames() const { return frames_; }
  const FrameStats& stats() const { return stats_; }
  const dance::v1::StreamEnd& end() const { return end_; }
  const std::vector<dance::v1::Event>& events() const { return events_; }
  bool got_info() const { return got_info_; }
  bool got_end() const { return got_end_; }
  // Audio sample frames (at the source's rate) handed to gRPC so far (thread-safe).
  int64_t audio_frames_sent() const;
  SampleSource* source() { return source_.get(); }

  void OnWriteDone(bool ok) override;
  void OnReadDone(bool ok) override;
  void OnDone(const grpc::Status& status) override;

 private:
  // Decides the next message under mu_; returns true if one was prepared in out_.
  bool PrepareNextLocked(absl::Time now) ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  void HandleUpdate(const dance::v1::DanceUpdate& u, absl::Time arrival);

  grpc::ClientContext context_;
  std::unique_ptr<SampleSource> source_;
  const PerformOptions options_;
  int64_t chunk_frames_ = 0;
  absl::Time t0_;

  mutable absl::Mutex mu_;
  bool header_sent_ ABSL_GUARDED_BY(mu_) = false;
  bool end_sent_ ABSL_GUARDED_BY(mu_) = false;
  bool writes_done_ ABSL_GUARDED_BY(mu_) = false;
  bool writing_ ABSL_GUARDED_BY(mu_) = false;
  bool stop_writing_ ABSL_GUARDED_BY(mu_) = false;
  bool hold_released_ ABSL_GUARDED_BY(mu_) = false;
  int64_t sent_frames_ ABSL_GUARDED_BY(mu_) = 0;
  size_t next_control_ ABSL_GUARDED_BY(mu_) = 0;
  dance::v1::PerformRequest out_ ABSL_GUARDED_BY(mu_);
  std::vector<std::pair<int64_t, absl::Time>> chunk_sent_ ABSL_GUARDED_BY(mu_);  // (end sample, send time)
  bool done_ ABSL_GUARDED_BY(mu_) = false;
  grpc::Status status_ ABSL_GUARDED_BY(mu_);
  int64_t frames_count_ ABSL_GUARDED_BY(mu_) = 0;
  std::string session_id_ ABSL_GUARDED_BY(mu_);

  // Reader side (reaction thread only, read after Wait).
  dance::v1::DanceUpdate in_;
  dance::v1::SessionInfo info_;
  std::vector<dance::v1::PoseFrame> frames_;
  dance::v1::StreamEnd end_;
  std::vector<dance::v1::Event> events_;
  bool got_info_ = false;
  bool got_end_ = false;
  FrameStats stats_;
  int64_t next_index_ = -1;
  std::vector<float> scratch_;
};

}  // namespace dance::client

#endif  // DANCE_CLIENT_PERFORM_STREAM_H_
