// LiveSession: one performer's stream inside the server: the engine stream, the inbox fed by the network
// side, and the fan-out of updates to the performer and its viewers. It speaks core types only
// (update.h); the sinks encode.
//
// Two sides, two threads:
//   network side (the transports' threads): EnqueueAudio / EnqueueControl / EnqueueEnd / Fail,
//     AttachPerformer / AddViewer / RemoveViewer, Summary. These only take the session's mutexes briefly.
//   scheduler side (exactly one scheduler thread owns the session): Drain, CheckTimeouts, StepsReady,
//     engine_stream, AfterStep, ReadyToComplete, Complete. Only this thread touches the engine stream.
// A session is shared (std::shared_ptr) by the hub's registry, its scheduler and the network handlers; it
// ends exactly once, in Complete(), called by its scheduler.
//
// Fan-out: every update is built once, as one shared immutable Update, and handed to every sink; a sink
// that needs a wire form asks the update for it (memoised per form), so N viewers cost one encoding per
// form, not N.
//
// Flow control: EnqueueAudio reports when the inbox holds more than `max_pending_samples`; the network side
// then stops reading and the scheduler calls the resumer registered with SetReadResumer after draining.
#ifndef DANCE_SERVER_CORE_LIVE_SESSION_H_
#define DANCE_SERVER_CORE_LIVE_SESSION_H_

#include <atomic>
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "absl/base/thread_annotations.h"
#include "absl/status/status.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"
#include "server/core/engine_port.h"
#include "server/core/frame_sink.h"
#include "server/core/metrics.h"
#include "server/core/stream_request.h"
#include "server/core/update.h"

namespace dance::server {

struct SessionSettings {
  std::string id;
  std::string client_name;
  StreamConfig config;
  PcmFormat format = PcmFormat::kF32Le;
  int64_t max_pending_samples = 24000 * 10;  // inbox bound before reads pause, input sample frames
  int max_viewers = 64;
  absl::Duration idle_timeout = absl::Seconds(30);
  absl::Duration max_duration = absl::Hours(4);
  // The performer's queued updates above which the session is not stepped (flow control for clients that
  // stream faster than real time), and how long it may stay there before the session fails with
  // RESOURCE_EXHAUSTED (a client that stopped reading).
  size_t output_soft_limit = 64;
  absl::Duration stall_timeout = absl::Seconds(10);
  // How long the session waits for live poses (PoseInput) before it ends the given part and dances on.
  absl::Duration pose_timeout = absl::Seconds(1);
  // Called (without locks held) after anything is queued, to wake the owning scheduler. May be empty.
  std::function<void()> wake;
};

// A live session as ListSessions and /api/sessions show it.
struct SessionSummary {
  std::string session_id;
  std::string client_name;
  int64_t started_unix_ms = 0;  // ms since the Unix epoch
  int64_t frames = 0;           // frames produced so far
  double audio_ms = 0.0;        // audio received so far, ms
  int viewers = 0;
  StyleMix style;               // the style mix in effect (the latest one queued)
};

class LiveSession {
 public:
  LiveSession(SessionSettings settings, std::unique_ptr<EngineStream> stream, const ModelDescription& model,
              ServerMetrics* metrics, absl::Time now);
  LiveSession(const LiveSession&) = delete;
  LiveSession& operator=(const LiveSession&) = delete;

  const std::string& id() const { return settings_.id; }
  const SessionSettings& settings() const { return settings_; }
  // The InfoUpdate every sink receives first.
  const UpdatePtr& info() const { return info_; }

  // ---- network side (any thread) ----
  // Queues one chunk of raw PCM (whole sample frames, already size-checked). INVALID_ARGUMENT if the offset
  // is not the next expected one or audio follows EndOfAudio; FAILED_PRECONDITION if the session is over.
  // *pause_reading is set when the inbox is over its bound (then wait for the resumer).
  absl::Status EnqueueAudio(int64_t sample_offset, std::string pcm, absl::Time arrival, bool* pause_reading);
  absl::Status EnqueueControl(ValidatedControl control);
  // Queues live poses, arrived at `arrival` (checked when drained: a bad one is refused with a warning).
  absl::Status EnqueuePoses(std::vector<PoseRequest> poses, absl::Time arrival);
  absl::Status EnqueueEnd(absl::Time arrival);
  // Ends the session with `status` (not OK) at the scheduler's next pass. First failure wins. Returns
  // false if the session is already over (completed), true otherwise.
  bool Fail(const absl::Status& status);
  void SetReadResumer(std::function<void()> resumer);
  // The performer's sink; receives info immediately.
  void AttachPerformer(std::shared_ptr<FrameSink> sink);
  // NOT_FOUND if the session is over, RESOURCE_EXHAUSTED at max_viewers. Delivers info immediately.
  absl::Status AddViewer(std::shared_ptr<FrameSink> sink);
  void RemoveViewer(const FrameSink* sink);
  int viewer_count() const;
  SessionSummary Summary() const;
  bool has_pending_work() const;

  // ---- scheduler side (the owning scheduler thread only) ----
  // Feeds queued audio/controls/end into the engine. An error ends the session (caller calls Complete).
  absl::Status Drain(absl::Time now);
  // DEADLINE_EXCEEDED after idle_timeout without audio or max_duration in total; also returns a pending
  // Fail() status. Idle time is measured from the last chunk's arrival at the server (not from when this
  // scheduler drained it), and never runs while audio is waiting in the inbox or reading is paused by
  // flow control: a server too busy to keep up must not blame the client.
  absl::Status CheckHealth(absl::Time now);
  int StepsReady() const { return stream_->StepsReady(); }
  // Whether to put this session in the next batch: a step is ready, the performer is not backlogged, and
  // live poses (if any come in) reach the frames the step needs, or stopped coming for pose_timeout (then
  // the given part ends with a warning). Applies pending controls first (a warning if they fail).
  bool ReadyToStep(absl::Time now);
  // True while the performer's backlog is above output_soft_limit (then do not step this session).
  bool OutputBacklogged(absl::Time now);
  EngineStream* engine_stream() { return stream_.get(); }
  // After the engine stepped this session once: collect frames, stamp them, fan them out.
  void AfterStep(absl::Time now);
  // EndOfAudio was drained and no step remains.
  bool ReadyToComplete() const;
  // Ends the session: publishes any tail frames and StreamEnd (if OK). Then the caller does its
  // bookkeeping (registry, metrics) and calls CloseSinks, so that a client that sees its call end also
  // sees the session gone from ListSessions, /api/sessions and the metrics. Idempotent. Returns the
  // status the session really ends with: an OK `status` yields to a Fail() that raced it (posted after
  // the scheduler's last health check), so a failure accepted by Fail() is never lost.
  absl::Status Complete(const absl::Status& status);
  // Closes the performer's and viewers' sinks with the status given to Complete. Idempotent.
  void CloseSinks();
  bool completed() const { return completed_; }

 private:
  struct InboxItem {
    enum class Kind { kAudio, kControl, kPoses, kEnd };
    Kind kind = Kind::kAudio;
    std::string pcm;
    int64_t end_sample = 0;
    absl::Time arrival;
    ValidatedControl control;
    std::vector<PoseRequest> poses;
  };
  // Which chunk made the engine's step count reach `steps_total`.
  struct TriggerMark {
    int64_t steps_total;
    int64_t end_sample;
    absl::Time arrival;
  };

  absl::Status QueueAudio(int64_t sample_offset, std::string pcm, absl::Time arrival,
                                  bool* pause_reading);
  absl::Status QueueControl(ValidatedControl control);
  absl::Status QueueEnd(absl::Time arrival);
  // Publishes the frames the engine has produced. `audio_trigger`: the frames were released by the audio
  // just drained (a tempo-normalised model emits a frame once its audio has arrived), so that chunk, not
  // the one that made the last step ready, is what their latency is measured from.
  void PublishFrames(absl::Time now, const TriggerMark* audio_trigger = nullptr);
  void Publish(const std::vector<UpdatePtr>& updates);
  void PublishOne(UpdatePtr update);
  void PushEvent(EventKind kind, std::string message);
  // Publishes the beats the engine found in the audio drained so far as KIND_BEAT events (time_ms: the
  // beat's audio time; frame_index: its 30 fps frame). They run ahead of the frames of their time.
  void PublishBeats();
  UpdatePtr EndUpdateNow(const char* reason) const;
  absl::Status PushPcm(const InboxItem& item);
  void RecordTrigger(int64_t end_sample, absl::Time arrival);

  const SessionSettings settings_;
  const std::unique_ptr<EngineStream> stream_;
  ServerMetrics* const metrics_;
  const absl::Time started_;
  UpdatePtr info_;

  mutable absl::Mutex inbox_mu_;
  std::vector<InboxItem> inbox_ ABSL_GUARDED_BY(inbox_mu_);
  int64_t pending_samples_ ABSL_GUARDED_BY(inbox_mu_) = 0;
  int64_t next_offset_ ABSL_GUARDED_BY(inbox_mu_) = 0;
  bool end_queued_ ABSL_GUARDED_BY(inbox_mu_) = false;
  bool reader_paused_ ABSL_GUARDED_BY(inbox_mu_) = false;
  std::function<void()> resumer_ ABSL_GUARDED_BY(inbox_mu_);
  std::optional<absl::Status> failure_ ABSL_GUARDED_BY(inbox_mu_);
  std::optional<StyleMix> current_style_ ABSL_GUARDED_BY(inbox_mu_);
  bool closed_ ABSL_GUARDED_BY(inbox_mu_) = false;
  absl::Time last_arrival_ ABSL_GUARDED_BY(inbox_mu_);  // last audio chunk's arrival (network side)

  mutable absl::Mutex sinks_mu_;
  std::shared_ptr<FrameSink> performer_ ABSL_GUARDED_BY(sinks_mu_);
  std::vector<std::shared_ptr<FrameSink>> viewers_ ABSL_GUARDED_BY(sinks_mu_);
  bool sinks_closed_ ABSL_GUARDED_BY(sinks_mu_) = false;
  bool ended_ ABSL_GUARDED_BY(sinks_mu_) = false;  // Complete() ran: no new viewers

  // Progress counters, written by the scheduler, read by Summary (relaxed atomics).
  std::atomic<int64_t> frames_out_{0};
  std::atomic<int64_t> samples_in_{0};

  // Scheduler-thread state.
  std::deque<TriggerMark> triggers_;
  int64_t steps_done_ = 0;
  int64_t steps_marked_ = 0;
  bool end_drained_ = false;
  absl::Status final_status_;
  std::optional<absl::Time> backlogged_since_;
  std::optional<absl::Time> last_pose_arrival_;  // of the newest live pose drained
  std::optional<absl::Time> last_pose_warning_;
  std::vector<LivePose> pose_buf_;
  bool completed_ = false;
  std::vector<float> f32_buf_;
  std::vector<int16_t> s16_buf_;
  std::vector<FrameData> frame_buf_;
  std::vector<double> beat_buf_;
  std::vector<UpdatePtr> publish_buf_;
};

}  // namespace dance::server

#endif  // DANCE_SERVER_CORE_LIVE_SESSION_H_
