#include "server/grpc/edit_reactor.h"

#include <cmath>
#include <deque>
#include <memory>
#include <optional>
#include <string>
#include <utility>

#include "absl/base/thread_annotations.h"
#include "absl/strings/str_cat.h"
#include "absl/synchronization/mutex.h"
#include "server/core/stream_request.h"
#include "server/grpc/convert.h"
#include "server/grpc/dance_service.h"
#include "server/grpc/stream_writer.h"
#include "server/log.h"

namespace dance::server {
namespace {

using dance::v1::EditUpdate;

// The client's address without its port: the key of the per-client edit limit.
std::string ClientKey(const grpc::CallbackServerContext& context) {
  std::string peer = context.peer();
  const size_t colon = peer.rfind(':');
  const size_t first = peer.find(':');
  if (colon != std::string::npos && colon != first) peer.resize(colon);  // "ipv4:1.2.3.4:5678" -> "ipv4:1.2.3.4"
  return peer;
}

class EditReactor;

// What the reactor and the job's listener share; outlives the reactor (the job may report after the call
// ended). Once Finish is issued nothing touches the reactor again.
class EditChannel {
 public:
  explicit EditChannel(EditReactor* reactor) : reactor_(reactor) {}
  void Post(EditUpdate update, bool coalesce);
  void Close(const absl::Status& status);
  void OnWriteDone(bool ok);

 private:
  void Pump();

  absl::Mutex mu_;
  EditReactor* reactor_;
  std::deque<EditUpdate> queue_ ABSL_GUARDED_BY(mu_);
  EditUpdate current_;               // the message in flight
  bool writing_ ABSL_GUARDED_BY(mu_) = false;
  bool finished_ ABSL_GUARDED_BY(mu_) = false;
  std::optional<absl::Status> close_ ABSL_GUARDED_BY(mu_);
};

class EditReactor final : public grpc::ServerWriteReactor<EditUpdate> {
 public:
  EditReactor(DanceServiceImpl* service, grpc::CallbackServerContext* context, const dance::v1::EditRequest& request)
      : channel_(std::make_shared<EditChannel>(this)), metrics_(service->metrics()) {
    absl::Status st = service->CheckAuth(*context);
    EditJobs* jobs = service->edit_jobs();
    if (st.ok() && jobs == nullptr) {
      st = absl::UnimplementedError("this server has no editor model (start it with --editor-model)");
    }
    if (st.ok() && !service->hub()->serving()) st = absl::UnavailableError("the server is draining");
    absl::StatusOr<EditConfig> config =
        st.ok() ? EditConfigFromProto(request, jobs->editor()->Describe()) : absl::StatusOr<EditConfig>(st);
    if (!config.ok()) {
      metrics_->CountError(config.status().code());
      channel_->Close(config.status());
      return;
    }
    const bool with_rotations = !request.omit_rotations();
    const EditorDescription& editor = jobs->editor()->Describe();
    std::weak_ptr<EditChannel> weak = channel_;
    const std::string client = ClientKey(*context);
    const std::string name = request.client_name();
    absl::StatusOr<std::shared_ptr<EditJob>> job = jobs->Submit(
        client, *std::move(config), [weak, with_rotations, &editor, name](const EditEvent& e) {
          std::shared_ptr<EditChannel> ch = weak.lock();
          if (ch == nullptr) return;
          EditUpdate u;
          switch (e.kind) {
            case EditEvent::Kind::kQueued:
              u.mutable_queued()->set_position(e.position);
              ch->Post(std::move(u), false);
              break;
            case EditEvent::Kind::kProgress:
              u.mutable_progress()->set_steps_done(e.progress.steps_done);
              u.mutable_progress()->set_steps_total(e.progress.steps_total);
              ch->Post(std::move(u), true);
              break;
            case EditEvent::Kind::kDone:
              Log(e.status.ok() ? LogLevel::kInfo : LogLevel::kWarning, "edit_done",
                  {{"client", name}, {"status", e.status.ToString()}, {"compute_s", e.compute_s}});
              if (e.status.ok()) {
                EditResultToProto(*e.output, editor, with_rotations, e.compute_s, u.mutable_result());
                ch->Post(std::move(u), false);
              }
              ch->Close(e.status);
              break;
          }
        });
    if (!job.ok()) {
      metrics_->CountError(job.status().code());
      channel_->Close(job.status());
      return;
    }
    job_ = *std::move(job);
  }

  void OnWriteDone(bool ok) override { channel_->OnWriteDone(ok); }
  void OnCancel() override {
    if (job_ != nullptr) job_->Cancel();
    channel_->Close(absl::CancelledError("the client cancelled the edit"));
  }
  void OnDone() override { delete this; }

 private:
  std::shared_ptr<EditChannel> channel_;
  ServerMetrics* const metrics_;
  std::shared_ptr<EditJob> job_;
};

void EditChannel::Post(EditUpdate update, bool coalesce) {
  {
    absl::MutexLock lock(&mu_);
    if (finished_ || close_.has_value()) return;
    if (coalesce && !queue_.empty() && queue_.back().has_progress()) {
      queue_.back() = std::move(update);
    } else {
      queue_.push_back(std::move(update));
    }
  }
  Pump();
}

void EditChannel::Close(const absl::Status& status) {
  {
    absl::MutexLock lock(&mu_);
    if (close_.has_value()) return;
    close_ = status;
    if (!status.ok()) queue_.clear();
  }
  Pump();
}

void EditChannel::OnWriteDone(bool ok) {
  {
    absl::MutexLock lock(&mu_);
    writing_ = false;
    if (!ok) {
      queue_.clear();
      if (!close_.has_value()) close_ = absl::CancelledError("the client went away");
    }
  }
  Pump();
}

void EditChannel::Pump() {
  enum { kNothing, kWrite, kFinish } op = kNothing;
  absl::Status status;
  {
    absl::MutexLock lock(&mu_);
    if (writing_ || finished_) return;
    if (!queue_.empty()) {
      current_ = std::move(queue_.front());
      queue_.pop_front();
      writing_ = true;
      op = kWrite;
    } else if (close_.has_value()) {
      finished_ = true;
      status = *close_;
      op = kFinish;
    }
  }
  if (op == kWrite) reactor_->StartWrite(&current_);
  if (op == kFinish) reactor_->Finish(ToGrpcStatus(status));
}

}  // namespace

absl::StatusOr<EditConfig> EditConfigFromProto(const dance::v1::EditRequest& r, const EditorDescription& editor) {
  EditConfig c;
  if (r.client_name().size() > 64) return absl::InvalidArgumentError("client_name: longer than 64 bytes");
  c.audio = r.audio();
  c.audio_name = r.audio_name().empty() ? "audio" : r.audio_name().substr(0, 200);
  c.style = StyleFromProto(r.style());
  c.seed = r.seed();
  c.steps = r.steps();
  c.guidance = r.guidance();
  c.overlap_s = r.overlap_s();
  c.foot_lock = !r.raw_feet();
  if (r.has_controls()) c.controls = ControlsFromProto(r.controls());
  if (absl::Status st = ValidateEditConfig(c, editor); !st.ok()) return st;
  return c;
}

void EditResultToProto(const EditOutput& out, const EditorDescription& editor, bool with_rotations, double compute_s,
                       dance::v1::EditResult* result) {
  result->set_model_id(editor.model_id);
  result->set_fps(30.0);
  dance::v1::Skeleton* sk = result->mutable_skeleton();
  for (const std::string& n : editor.joint_names) sk->add_joint_names(n);
  for (int p : editor.parents) sk->add_parents(p);
  for (float v : editor.rest_offsets) sk->add_rest_offsets(v);
  result->mutable_frames()->Reserve(static_cast<int>(out.frames.size()));
  for (const FrameData& f : out.frames) {
    dance::v1::PoseFrame* p = result->add_frames();
    p->set_index(f.index);
    p->set_time_ms(f.time_s * 1000.0);
    p->mutable_positions()->Add(f.positions.begin(), f.positions.end());
    if (with_rotations) p->mutable_rotations()->Add(f.rotations.begin(), f.rotations.end());
    p->set_upper_code(f.upper_code);
    p->set_lower_code(f.lower_code);
  }
  result->set_windows(out.windows);
  result->set_steps(out.steps);
  result->set_guidance(out.guidance);
  result->set_overlap_s(static_cast<float>(out.overlap_s));
  result->set_audio_ms(out.audio_s * 1000.0);
  result->set_compute_ms(compute_s * 1000.0);
}

void EditorToProto(const EditJobs& jobs, dance::v1::EditorInfo* out) {
  const EditorDescription& d = jobs.editor()->Describe();
  out->set_model_id(d.model_id);
  for (const std::string& s : d.styles) out->add_styles(s);
  out->set_default_steps(d.default_steps);
  out->set_default_guidance(d.default_guidance);
  out->set_default_overlap_s(static_cast<float>(d.default_overlap_s));
  out->set_window_s(d.window_s);
  out->set_workers(jobs.options().workers);
  out->set_max_queued(jobs.options().max_queued);
  out->set_max_per_client(jobs.options().max_per_client);
  out->set_max_audio_s(jobs.options().max_audio_s);
}

grpc::ServerWriteReactor<EditUpdate>* NewEditReactor(DanceServiceImpl* service, grpc::CallbackServerContext* context,
                                                     const dance::v1::EditRequest& request) {
  return new EditReactor(service, context, request);
}

}  // namespace dance::server
