#include "client/perform_stream.h"

#include <algorithm>
#include <cstring>

#include "absl/strings/str_cat.h"
#include "absl/time/clock.h"

namespace dance::client {

PerformStream::PerformStream(dance::v1::DanceService::Stub* stub, std::unique_ptr<SampleSource> source,
                             PerformOptions options)
    : source_(std::move(source)), options_(std::move(options)) {
  if (!options_.auth_token.empty()) context_.AddMetadata("authorization", "Bearer " + options_.auth_token);
  chunk_frames_ = std::max<int64_t>(1, int64_t{source_->sample_rate()} * options_.chunk_ms / 1000);
  stub->async()->Perform(&context_, this);
}

void PerformStream::Start(absl::Time t0) {
  t0_ = t0;
  source_->Start(t0);
  AddHold();  // writes are started from the pacer thread: keep OnDone away until the writer side is done
  StartRead(&in_);
  StartCall();
  Pump(t0);
}

bool PerformStream::PrepareNextLocked(absl::Time now) {
  if (writing_ || stop_writing_ || writes_done_) return false;
  out_.Clear();
  if (!header_sent_) {
    dance::v1::StreamHeader* h = out_.mutable_header();
    *h = options_.header;
    h->set_sample_rate_hz(source_->sample_rate());
    h->set_channels(source_->channels());
    h->set_sample_format(dance::v1::SAMPLE_FORMAT_F32LE);
    h->set_client_time_us(absl::ToUnixMicros(now));
    header_sent_ = true;
    return true;
  }
  if (next_control_ < options_.controls.size() &&
      sent_frames_ >= static_cast<int64_t>(options_.controls[next_control_].at_s * source_->sample_rate())) {
    *out_.mutable_control() = options_.controls[next_control_++].control;
    return true;
  }
  const int64_t available = source_->Available(now);
  const int64_t total = source_->Total();
  const int64_t ready = available - sent_frames_;
  const bool last = total >= 0 && available >= total;
  if (ready >= chunk_frames_ || (last && ready > 0)) {
    const int64_t n = std::min(ready, chunk_frames_);
    source_->Read(sent_frames_, n, &scratch_);
    dance::v1::AudioChunk* a = out_.mutable_audio();
    a->set_sample_offset(sent_frames_);
    a->set_pcm(reinterpret_cast<const char*>(scratch_.data()), scratch_.size() * sizeof(float));
    sent_frames_ += n;
    chunk_sent_.emplace_back(sent_frames_, now);
    return true;
  }
  if (last && !end_sent_) {
    out_.mutable_end();
    end_sent_ = true;
    return true;
  }
  return false;
}

void PerformStream::Pump(absl::Time now) {
  bool write = false;
  bool finish_writes = false;
  {
    absl::MutexLock lock(&mu_);
    write = PrepareNextLocked(now);
    if (write) {
      writing_ = true;
    } else if (end_sent_ && !writing_ && !writes_done_ && !stop_writing_) {
      writes_done_ = true;
      finish_writes = true;
    }
  }
  if (write) {
    StartWrite(&out_);
  } else if (finish_writes) {
    StartWritesDone();
  }
}

void PerformStream::OnWriteDone(bool ok) {
  bool release = false;
  {
    absl::MutexLock lock(&mu_);
    writing_ = false;
    if (!ok) stop_writing_ = true;
    if ((stop_writing_ || writes_done_) && !hold_released_) {
      hold_released_ = true;
      release = true;
    }
  }
  if (release) {
    RemoveHold();
    return;
  }
  Pump(absl::Now());  // in fast mode this keeps the pipe full; in real time it sends what is due
}

void PerformStream::OnReadDone(bool ok) {
  if (!ok) {
    bool release = false;
    {
      absl::MutexLock lock(&mu_);
      stop_writing_ = true;
      if (!writing_ && !hold_released_) {
        hold_released_ = true;
        release = true;
      }
    }
    if (release) RemoveHold();
    return;
  }
  HandleUpdate(in_, absl::Now());
  StartRead(&in_);
}

void PerformStream::HandleUpdate(const dance::v1::DanceUpdate& u, absl::Time arrival) {
  switch (u.kind_case()) {
    case dance::v1::DanceUpdate::kInfo: {
      info_ = u.info();
      got_info_ = true;
      absl::MutexLock lock(&mu_);
      session_id_ = info_.session_id();
      break;
    }
    case dance::v1::DanceUpdate::kFrame: {
      const dance::v1::PoseFrame& f = u.frame();
      if (next_index_ >= 0 && f.index() > next_index_) stats_.gaps += f.index() - next_index_;
      next_index_ = f.index() + 1;
      absl::Time sent = arrival;
      {
        absl::MutexLock lock(&mu_);
        ++frames_count_;
        auto it = std::lower_bound(chunk_sent_.begin(), chunk_sent_.end(),
                                   std::make_pair(f.trigger_sample_end(), absl::InfinitePast()));
        if (it != chunk_sent_.end() && it->first == f.trigger_sample_end()) sent = it->second;
      }
      const double latency_ms = absl::ToDoubleMilliseconds(arrival - sent);
      stats_.latency_ms.push_back(static_cast<float>(latency_ms));
      if (latency_ms >= kSlowFrameMs) {
        const double server_ms = absl::ToDoubleMilliseconds(absl::FromUnixMicros(f.server_time_us()) - sent);
        stats_.slow.push_back({static_cast<float>(absl::ToDoubleSeconds(arrival - t0_)),
                               static_cast<float>(latency_ms), static_cast<float>(server_ms)});
      }
      stats_.max_skew_ms = std::max(stats_.max_skew_ms, absl::ToDoubleMilliseconds(arrival - t0_) - f.time_ms());
      ++stats_.frames;
      if (options_.keep_frames) frames_.push_back(f);
      break;
    }
    case dance::v1::DanceUpdate::kEvent:
      events_.push_back(u.event());
      break;
    case dance::v1::DanceUpdate::kEnd:
      end_ = u.end();
      got_end_ = true;
      break;
    default:
      break;
  }
}

void PerformStream::OnDone(const grpc::Status& status) {
  absl::MutexLock lock(&mu_);
  status_ = status;
  done_ = true;
}

bool PerformStream::done() const {
  absl::MutexLock lock(&mu_);
  return done_;
}

int64_t PerformStream::frames_received() const {
  absl::MutexLock lock(&mu_);
  return frames_count_;
}

int64_t PerformStream::audio_frames_sent() const {
  absl::MutexLock lock(&mu_);
  return sent_frames_;
}

std::string PerformStream::session_id() const {
  absl::MutexLock lock(&mu_);
  return session_id_;
}

absl::Status PerformStream::Wait() {
  absl::MutexLock lock(&mu_);
  mu_.Await(absl::Condition(&done_));
  return absl::Status(static_cast<absl::StatusCode>(status_.error_code()), status_.error_message());
}

}  // namespace dance::client
