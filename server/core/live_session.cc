#include "server/core/live_session.h"

#include <algorithm>
#include <cstring>
#include <optional>
#include <utility>

#include "absl/strings/str_cat.h"

namespace dance::server {
namespace {

int64_t UnixMicros(absl::Time t) { return absl::ToUnixMicros(t); }

}  // namespace

LiveSession::LiveSession(SessionSettings settings, std::unique_ptr<EngineStream> stream,
                         const ModelDescription& model, ServerMetrics* metrics, absl::Time now)
    : settings_(std::move(settings)),
      stream_(std::move(stream)),
      metrics_(metrics),
      started_(now),
      last_arrival_(now) {
  info_ = std::make_shared<const Update>(InfoUpdate{settings_.id, model});
  current_style_ = settings_.config.style;
}

absl::Status LiveSession::QueueAudio(int64_t sample_offset, std::string pcm, absl::Time arrival,
                                             bool* pause_reading) {
  *pause_reading = false;
  const int64_t frame_bytes = int64_t{BytesPerSample(settings_.format)} * settings_.config.channels;
  const int64_t frames = static_cast<int64_t>(pcm.size()) / frame_bytes;
  absl::MutexLock lock(&inbox_mu_);
  if (closed_) return absl::FailedPreconditionError("session is over");
  if (end_queued_) return absl::InvalidArgumentError("audio after EndOfAudio");
  if (sample_offset != next_offset_) {
    return absl::InvalidArgumentError(absl::StrCat("audio chunk sample_offset ", sample_offset,
                                                   " but ", next_offset_, " sample frames were sent before it"));
  }
  next_offset_ += frames;
  pending_samples_ += frames;
  InboxItem item;
  item.kind = InboxItem::Kind::kAudio;
  item.pcm = std::move(pcm);
  item.end_sample = next_offset_;
  item.arrival = arrival;
  inbox_.push_back(std::move(item));
  last_arrival_ = std::max(last_arrival_, arrival);
  if (pending_samples_ > settings_.max_pending_samples) {
    reader_paused_ = true;
    *pause_reading = true;
  }
  return absl::OkStatus();
}

absl::Status LiveSession::EnqueueAudio(int64_t sample_offset, std::string pcm, absl::Time arrival,
                                       bool* pause_reading) {
  absl::Status s = QueueAudio(sample_offset, std::move(pcm), arrival, pause_reading);
  if (s.ok() && settings_.wake) settings_.wake();
  return s;
}

absl::Status LiveSession::QueueControl(ValidatedControl control) {
  absl::MutexLock lock(&inbox_mu_);
  if (closed_) return absl::FailedPreconditionError("session is over");
  if (control.style) current_style_ = control.style;
  InboxItem item;
  item.kind = InboxItem::Kind::kControl;
  item.control = std::move(control);
  inbox_.push_back(std::move(item));
  return absl::OkStatus();
}

absl::Status LiveSession::EnqueueControl(ValidatedControl control) {
  absl::Status s = QueueControl(std::move(control));
  if (s.ok() && settings_.wake) settings_.wake();
  return s;
}

absl::Status LiveSession::EnqueuePoses(std::vector<PoseRequest> poses, absl::Time arrival) {
  {
    absl::MutexLock lock(&inbox_mu_);
    if (closed_) return absl::FailedPreconditionError("session is over");
    InboxItem item;
    item.kind = InboxItem::Kind::kPoses;
    item.poses = std::move(poses);
    item.arrival = arrival;
    inbox_.push_back(std::move(item));
  }
  if (settings_.wake) settings_.wake();
  return absl::OkStatus();
}

absl::Status LiveSession::QueueEnd(absl::Time arrival) {
  absl::MutexLock lock(&inbox_mu_);
  if (closed_) return absl::FailedPreconditionError("session is over");
  if (end_queued_) return absl::InvalidArgumentError("EndOfAudio sent twice");
  end_queued_ = true;
  InboxItem item;
  item.kind = InboxItem::Kind::kEnd;
  item.end_sample = next_offset_;
  item.arrival = arrival;
  inbox_.push_back(std::move(item));
  return absl::OkStatus();
}

absl::Status LiveSession::EnqueueEnd(absl::Time arrival) {
  absl::Status s = QueueEnd(arrival);
  if (s.ok() && settings_.wake) settings_.wake();
  return s;
}

bool LiveSession::Fail(const absl::Status& status) {
  {
    absl::MutexLock lock(&inbox_mu_);
    if (closed_) return false;
    if (failure_) return true;
    failure_ = status.ok() ? absl::InternalError("Fail(OK)") : status;
  }
  if (settings_.wake) settings_.wake();
  return true;
}

void LiveSession::SetReadResumer(std::function<void()> resumer) {
  absl::MutexLock lock(&inbox_mu_);
  resumer_ = std::move(resumer);
}

bool LiveSession::has_pending_work() const {
  absl::MutexLock lock(&inbox_mu_);
  return !inbox_.empty() || failure_.has_value();
}

void LiveSession::AttachPerformer(std::shared_ptr<FrameSink> sink) {
  sink->Deliver(info_);
  absl::MutexLock lock(&sinks_mu_);
  performer_ = std::move(sink);
}

absl::Status LiveSession::AddViewer(std::shared_ptr<FrameSink> sink) {
  absl::MutexLock lock(&sinks_mu_);
  if (sinks_closed_ || ended_) return absl::NotFoundError(absl::StrCat("session ", settings_.id, " has ended"));
  if (static_cast<int>(viewers_.size()) >= settings_.max_viewers) {
    return absl::ResourceExhaustedError(
        absl::StrCat("session ", settings_.id, " already has ", viewers_.size(), " viewers"));
  }
  sink->Deliver(info_);  // before it can see any frame: frames are published under this lock's snapshot
  viewers_.push_back(std::move(sink));
  return absl::OkStatus();
}

void LiveSession::RemoveViewer(const FrameSink* sink) {
  absl::MutexLock lock(&sinks_mu_);
  viewers_.erase(std::remove_if(viewers_.begin(), viewers_.end(),
                                [sink](const std::shared_ptr<FrameSink>& v) { return v.get() == sink; }),
                 viewers_.end());
}

int LiveSession::viewer_count() const {
  absl::MutexLock lock(&sinks_mu_);
  return static_cast<int>(viewers_.size());
}

SessionSummary LiveSession::Summary() const {
  SessionSummary s;
  s.session_id = settings_.id;
  s.client_name = settings_.client_name;
  s.started_unix_ms = absl::ToUnixMillis(started_);
  s.frames = frames_out_.load(std::memory_order_relaxed);
  s.audio_ms = 1000.0 * static_cast<double>(samples_in_.load(std::memory_order_relaxed)) /
               settings_.config.sample_rate_hz;
  s.viewers = viewer_count();
  absl::MutexLock lock(&inbox_mu_);
  if (current_style_) s.style = *current_style_;
  return s;
}

absl::Status LiveSession::PushPcm(const InboxItem& item) {
  const size_t n = item.pcm.size() / BytesPerSample(settings_.format);
  // Copy out of the byte string: it has no float alignment guarantee.
  if (settings_.format == PcmFormat::kF32Le) {
    f32_buf_.resize(n);
    std::memcpy(f32_buf_.data(), item.pcm.data(), n * sizeof(float));
    return stream_->PushAudio(f32_buf_);
  }
  s16_buf_.resize(n);
  std::memcpy(s16_buf_.data(), item.pcm.data(), n * sizeof(int16_t));
  return stream_->PushAudioInt16(s16_buf_);
}

void LiveSession::RecordTrigger(int64_t end_sample, absl::Time arrival) {
  const int64_t total = steps_done_ + stream_->StepsReady();
  if (total > steps_marked_) {
    triggers_.push_back({total, end_sample, arrival});
    steps_marked_ = total;
  }
}

absl::Status LiveSession::Drain(absl::Time now) {
  std::vector<InboxItem> items;
  std::function<void()> resume;
  {
    absl::MutexLock lock(&inbox_mu_);
    items.swap(inbox_);
    pending_samples_ = 0;
    if (reader_paused_) {
      reader_paused_ = false;
      resume = resumer_;
    }
  }
  std::optional<TriggerMark> last_audio;  // the last audio chunk drained
  absl::Status pose_error;                // the first bad pose drained (one warning per pass)
  for (InboxItem& item : items) {
    switch (item.kind) {
      case InboxItem::Kind::kAudio: {
        absl::Status s = PushPcm(item);
        if (!s.ok()) return s;
        const int64_t frames = static_cast<int64_t>(item.pcm.size()) /
                               (BytesPerSample(settings_.format) * settings_.config.channels);
        samples_in_.fetch_add(frames, std::memory_order_relaxed);
        metrics_->audio_samples_total.fetch_add(frames, std::memory_order_relaxed);
        RecordTrigger(item.end_sample, item.arrival);
        last_audio = TriggerMark{0, item.end_sample, item.arrival};
        break;
      }
      case InboxItem::Kind::kControl: {
        const ValidatedControl& c = item.control;
        absl::Status s;
        if (c.style) s.Update(stream_->SetStyle(*c.style));
        if (c.sampling) s.Update(stream_->SetSampling(*c.sampling));
        if (c.controls) {
          absl::Status v = ValidateControlSpec(*c.controls);
          s.Update(v.ok() ? stream_->SetControls(*c.controls) : v);
        }
        if (c.steer) {
          absl::Status v = ValidateSteer(*c.steer);
          s.Update(v.ok() ? stream_->Steer(*c.steer) : v);
        }
        if (s.ok()) {
          PushEvent(EventKind::kControlApplied, "control applied");
        } else {
          PushEvent(EventKind::kWarning, absl::StrCat("control ignored: ", s.message()));
        }
        break;
      }
      case InboxItem::Kind::kPoses:
        for (const PoseRequest& r : item.poses) {
          absl::StatusOr<LivePose> p = ValidatePose(r);
          if (p.ok()) {
            pose_buf_.push_back(*p);
          } else if (pose_error.ok()) {
            pose_error = p.status();
          }
        }
        last_pose_arrival_ = item.arrival;
        break;
      case InboxItem::Kind::kEnd:
        stream_->EndOfAudio();
        end_drained_ = true;
        RecordTrigger(item.end_sample, item.arrival);
        break;
    }
  }
  if (!pose_buf_.empty()) {
    // All the poses of this pass at once: the controls are re-planned once per step, not per pose.
    pose_error.Update(stream_->PushPoses(pose_buf_));
    pose_buf_.clear();
  }
  if (!pose_error.ok() && (!last_pose_warning_ || now - *last_pose_warning_ >= absl::Seconds(1))) {
    // At most one a second: a client sending bad poses at 30 fps gets told, not flooded.
    PushEvent(EventKind::kWarning, absl::StrCat("pose ignored: ", pose_error.message()));
    last_pose_warning_ = now;
  }
  PublishBeats();
  // A tempo-normalised model emits real frames as their audio arrives (not only after a step): send them,
  // timed from the last audio chunk drained (the one that released them).
  if (last_audio.has_value()) PublishFrames(now, &*last_audio);
  if (resume) resume();
  return absl::OkStatus();
}

absl::Status LiveSession::CheckHealth(absl::Time now) {
  bool idle = false;
  {
    absl::MutexLock lock(&inbox_mu_);
    if (failure_) return *failure_;
    // Queued audio or paused reads: the server is behind, not the client.
    idle = !end_queued_ && !reader_paused_ && inbox_.empty() && now - last_arrival_ > settings_.idle_timeout;
  }
  if (idle && !end_drained_) {
    return absl::DeadlineExceededError(
        absl::StrCat("no audio for ", absl::FormatDuration(settings_.idle_timeout), " (idle timeout)"));
  }
  if (backlogged_since_ && now - *backlogged_since_ > settings_.stall_timeout) {
    return absl::ResourceExhaustedError(absl::StrCat("client is not reading its frames (stalled for ",
                                                     absl::FormatDuration(now - *backlogged_since_), ")"));
  }
  if (now - started_ > settings_.max_duration) {
    return absl::DeadlineExceededError(
        absl::StrCat("session longer than ", absl::FormatDuration(settings_.max_duration)));
  }
  return absl::OkStatus();
}

void LiveSession::PushEvent(EventKind kind, std::string message) {
  EventUpdate e;
  e.kind = kind;
  e.frame_index = frames_out_.load(std::memory_order_relaxed);
  e.time_ms = 1000.0 * static_cast<double>(samples_in_.load(std::memory_order_relaxed)) /
              settings_.config.sample_rate_hz;
  e.message = std::move(message);
  PublishOne(std::make_shared<const Update>(std::move(e)));
}

void LiveSession::PublishBeats() {
  beat_buf_.clear();
  stream_->PopBeats(&beat_buf_);
  for (double t : beat_buf_) {
    EventUpdate e;
    e.kind = EventKind::kBeat;
    e.time_ms = 1000.0 * t;
    e.frame_index = std::llround(30.0 * t);
    PublishOne(std::make_shared<const Update>(std::move(e)));
  }
  metrics_->beats_total.fetch_add(beat_buf_.size(), std::memory_order_relaxed);
}

void LiveSession::AfterStep(absl::Time now) {
  ++steps_done_;
  PublishFrames(now);
}

void LiveSession::PublishFrames(absl::Time now, const TriggerMark* audio_trigger) {
  while (!triggers_.empty() && triggers_.front().steps_total < steps_done_) triggers_.pop_front();
  int64_t trigger_end = 0;
  absl::Time trigger_arrival = now;
  if (audio_trigger != nullptr) {
    trigger_end = audio_trigger->end_sample;
    trigger_arrival = audio_trigger->arrival;
  } else if (!triggers_.empty()) {
    trigger_end = triggers_.front().end_sample;
    trigger_arrival = triggers_.front().arrival;
  }
  frame_buf_.clear();
  stream_->PopFrames(&frame_buf_);
  if (frame_buf_.empty()) return;
  metrics_->frame_latency.Observe(absl::ToDoubleSeconds(now - trigger_arrival));
  const int64_t server_time_us = UnixMicros(now);
  publish_buf_.clear();
  for (const FrameData& f : frame_buf_) {
    publish_buf_.push_back(std::make_shared<const Update>(FrameUpdate{f, trigger_end, server_time_us}));
  }
  frames_out_.fetch_add(static_cast<int64_t>(frame_buf_.size()), std::memory_order_relaxed);
  metrics_->frames_total.fetch_add(frame_buf_.size(), std::memory_order_relaxed);
  Publish(publish_buf_);
  publish_buf_.clear();
}

void LiveSession::Publish(const std::vector<UpdatePtr>& updates) {
  std::shared_ptr<FrameSink> performer;
  std::vector<std::shared_ptr<FrameSink>> viewers;
  {
    absl::MutexLock lock(&sinks_mu_);
    performer = performer_;
    viewers = viewers_;
  }
  // The same objects to every sink: each encodes an update into its wire form once for all sinks of
  // that form (update.h).
  auto send = [&](FrameSink* sink) {
    for (const UpdatePtr& u : updates) sink->Deliver(u);
  };
  if (performer) send(performer.get());
  for (const auto& v : viewers) send(v.get());
}

void LiveSession::PublishOne(UpdatePtr update) {
  const std::vector<UpdatePtr> one{std::move(update)};
  Publish(one);
}

UpdatePtr LiveSession::EndUpdateNow(const char* reason) const {
  EndUpdate e;
  e.frames = frames_out_.load();
  e.audio_ms = 1000.0 * static_cast<double>(samples_in_.load()) / settings_.config.sample_rate_hz;
  e.reason = reason;
  return std::make_shared<const Update>(std::move(e));
}

bool LiveSession::OutputBacklogged(absl::Time now) {
  size_t backlog = 0;
  {
    absl::MutexLock lock(&sinks_mu_);
    if (performer_ != nullptr) backlog = performer_->Backlog();
  }
  if (backlog <= settings_.output_soft_limit) {
    backlogged_since_.reset();
    return false;
  }
  if (!backlogged_since_) backlogged_since_ = now;
  return true;
}

bool LiveSession::ReadyToStep(absl::Time now) {
  if (completed_ || stream_->StepsReady() <= 0 || OutputBacklogged(now)) return false;
  if (stream_->WaitsForPoses()) {
    // After the end of the audio no pose can be due: the rig's last poses were for the song's last frames.
    if (end_drained_) {
      stream_->EndPoses();
    } else if (last_pose_arrival_.has_value() && now - *last_pose_arrival_ < settings_.pose_timeout) {
      return false;
    } else {
      stream_->EndPoses();
      PushEvent(EventKind::kWarning,
                absl::StrCat("pose input stopped: no pose for ", absl::FormatDuration(settings_.pose_timeout),
                             "; the given part ends and the dance goes on"));
    }
  }
  if (absl::Status s = stream_->CommitControls(); !s.ok()) {
    PushEvent(EventKind::kWarning, absl::StrCat("controls not applied: ", s.message()));
  }
  return true;
}

bool LiveSession::ReadyToComplete() const { return end_drained_ && stream_->StepsReady() == 0; }

absl::Status LiveSession::Complete(const absl::Status& requested) {
  if (completed_) return final_status_;
  completed_ = true;
  absl::Status status = requested;
  {
    absl::MutexLock lock(&inbox_mu_);
    if (status.ok() && failure_) status = *failure_;
    final_status_ = status;
    closed_ = true;
    inbox_.clear();
    resumer_ = nullptr;
  }
  {
    absl::MutexLock lock(&sinks_mu_);
    ended_ = true;
  }
  if (status.ok()) {
    PublishBeats();
    PublishFrames(absl::Now());  // the engine may flush a tail on EndOfAudio
    PublishOne(EndUpdateNow("end_of_audio"));
  }
  return status;
}

void LiveSession::CloseSinks() {
  const absl::Status status = final_status_;
  std::shared_ptr<FrameSink> performer;
  std::vector<std::shared_ptr<FrameSink>> viewers;
  {
    absl::MutexLock lock(&sinks_mu_);
    if (sinks_closed_) return;
    sinks_closed_ = true;
    performer = std::move(performer_);
    viewers.swap(viewers_);
  }
  if (performer) performer->Close(status);
  if (!status.ok() && !viewers.empty()) {
    // Viewers did nothing wrong: they see a normal end that says the session closed.
    const UpdatePtr u = EndUpdateNow("session_closed");
    for (const auto& v : viewers) v->Deliver(u);
  }
  for (const auto& v : viewers) v->Close(absl::OkStatus());
}

}  // namespace dance::server
