#include "server/grpc/dance_service.h"

#include <memory>
#include <utility>

#include "absl/strings/str_cat.h"
#include "absl/time/clock.h"
#include "server/grpc/convert.h"
#include "server/grpc/edit_reactor.h"
#include "server/grpc/stream_writer.h"
#include "server/log.h"

namespace dance::server {
namespace {

using dance::v1::DanceUpdate;
using dance::v1::PerformRequest;

// One Perform call. Lifetime: created by gRPC's Perform(), deleted in OnDone. All engine work happens on
// the session's scheduler thread; this class only validates and queues.
class PerformReactor final : public grpc::ServerBidiReactor<PerformRequest, DanceUpdate> {
 public:
  PerformReactor(DanceServiceImpl* service, grpc::CallbackServerContext* context)
      : service_(service),
        context_(context),
        writer_(std::make_shared<Writer>(this, Writer::Mode::kLossless, service->options().performer_queue_limit,
                                         /*wants_rotations=*/true, service->metrics())) {
    // An OK end waits for the client's half-close (bounded), so that anything it sends after EndOfAudio
    // is still seen and answered with INVALID_ARGUMENT (docs/protocol.md).
    writer_->RequireHalfCloseBeforeOk(service->options().half_close_grace);
    absl::Status auth = service_->CheckAuth(*context);
    if (!auth.ok()) {
      Fail(auth);
      return;
    }
    writer_->Read();
  }

  void IssueWrite(const DanceUpdate* update) { StartWrite(update); }
  void IssueRead() { StartRead(&request_); }
  void IssueFinish(grpc::Status status) { Finish(std::move(status)); }

  void OnReadDone(bool ok) override {
    if (!ok) {
      // Half-close (or a dead call). Without EndOfAudio a half-close still means "no more audio", but a
      // cancelled call is not a half-close: it must end CANCELLED, never OK (OnCancel may run after this).
      writer_->ReadsDone();
      if (context_->IsCancelled()) {
        OnCancel();  // idempotent; gRPC calls it too, maybe later
      } else if (auto s = session(); s == nullptr) {
        Fail(absl::InvalidArgumentError("stream closed before a StreamHeader"));
      } else if (!end_sent_) {
        end_sent_ = true;
        (void)s->EnqueueEnd(absl::Now());
      }
      return;
    }
    paused_ = false;
    absl::Status st = Handle();
    if (!st.ok()) {
      Fail(st);
      return;
    }
    if (!paused_) writer_->Read();  // else the session's scheduler resumes reading after draining
  }

  void OnWriteDone(bool ok) override { writer_->OnWriteDone(ok); }

  void OnCancel() override {
    const absl::Status cancelled = absl::CancelledError("client went away");
    // A session that already completed OK (e.g. its implicit end raced this cancel) ends CANCELLED too.
    if (auto s = session(); s != nullptr && !s->Fail(cancelled)) writer_->Abort(cancelled);
    writer_->Close(cancelled);
  }

  void OnDone() override {
    if (auto s = session()) s->Fail(absl::CancelledError("call ended"));
    delete this;
  }

 private:
  using Writer = StreamWriter<PerformReactor>;

  // session_ is written on the read path and read by OnCancel, which gRPC may run concurrently.
  std::shared_ptr<LiveSession> session() const {
    absl::MutexLock lock(&session_mu_);
    return session_;
  }

  absl::Status Handle() {
    const absl::Time now = absl::Now();
    switch (request_.kind_case()) {
      case PerformRequest::kHeader: {
        if (session() != nullptr) return absl::InvalidArgumentError("StreamHeader sent twice");
        absl::StatusOr<ValidatedStream> h =
            ValidateHeader(request_.header(), service_->hub()->model(), service_->options().limits);
        if (!h.ok()) return h.status();
        header_ = *std::move(h);
        absl::StatusOr<std::shared_ptr<LiveSession>> s =
            service_->hub()->Admit(header_.config, header_.format, header_.client_name);
        if (!s.ok()) {
          rejected_ = true;
          return s.status();
        }
        {
          absl::MutexLock lock(&session_mu_);
          session_ = *s;
        }
        writer_->SetWantsRotations(!header_.omit_rotations);
        // The resumer may run after this reactor is gone: it holds only the writer, whose Read() is a
        // no-op once the call is finished.
        std::weak_ptr<Writer> weak = writer_;
        (*s)->SetReadResumer([weak] {
          if (auto w = weak.lock()) w->Read();
        });
        (*s)->AttachPerformer(writer_);
        return absl::OkStatus();
      }
      case PerformRequest::kAudio: {
        if (session() == nullptr) return absl::InvalidArgumentError("audio before the StreamHeader");
        // Checked here, not only in the session: the session may already have completed.
        if (end_sent_) return absl::InvalidArgumentError("audio after EndOfAudio");
        absl::Status c = ValidateChunk(request_.audio().pcm().size(), header_, service_->options().limits);
        if (!c.ok()) return c;
        bool pause = false;
        absl::Status q = session()->EnqueueAudio(request_.audio().sample_offset(),
                                                std::move(*request_.mutable_audio()->mutable_pcm()), now, &pause);
        paused_ = pause;
        return q;
      }
      case PerformRequest::kControl: {
        if (session() == nullptr) return absl::InvalidArgumentError("control before the StreamHeader");
        absl::StatusOr<ValidatedControl> c =
            ValidateControl(ControlRequestFromProto(request_.control()), service_->hub()->model());
        if (!c.ok()) return c.status();
        absl::Status q = session()->EnqueueControl(*std::move(c));
        // A control racing the session's end is harmless ("any time after the header"): ignore it.
        if (q.code() == absl::StatusCode::kFailedPrecondition) return absl::OkStatus();
        return q;
      }
      case PerformRequest::kPoses: {
        if (session() == nullptr) return absl::InvalidArgumentError("poses before the StreamHeader");
        std::vector<PoseRequest> poses{PoseFromProto(request_.poses())};
        absl::Status q = session()->EnqueuePoses(std::move(poses), now);
        if (q.code() == absl::StatusCode::kFailedPrecondition) return absl::OkStatus();  // raced the end
        return q;
      }
      case PerformRequest::kEnd:
        if (session() == nullptr) return absl::InvalidArgumentError("EndOfAudio before the StreamHeader");
        if (end_sent_) return absl::InvalidArgumentError("EndOfAudio sent twice");
        end_sent_ = true;
        return session()->EnqueueEnd(now);
      default:
        return absl::InvalidArgumentError("empty PerformRequest");
    }
  }

  void Fail(const absl::Status& status) {
    std::shared_ptr<LiveSession> s = session();
    if (!rejected_ && s == nullptr) service_->metrics()->CountError(status.code());
    if (s != nullptr) {
      // The scheduler closes the writer with this status; if the session already completed (OK, its
      // finish waiting for our half-close), the protocol error replaces that OK here.
      if (!s->Fail(status)) writer_->Abort(status);
    } else {
      writer_->Close(status);
    }
    Log(LogLevel::kInfo, "perform_rejected",
        {{"status", absl::StatusCodeToString(status.code())}, {"message", status.message()}});
  }

  DanceServiceImpl* const service_;
  grpc::CallbackServerContext* const context_;
  std::shared_ptr<Writer> writer_;
  PerformRequest request_;
  ValidatedStream header_;
  mutable absl::Mutex session_mu_;
  std::shared_ptr<LiveSession> session_ ABSL_GUARDED_BY(session_mu_);  // set once, by the read path
  bool paused_ = false;  // reactor-thread only
  bool end_sent_ = false;
  bool rejected_ = false;
};

class WatchReactor final : public grpc::ServerWriteReactor<DanceUpdate> {
 public:
  WatchReactor(DanceServiceImpl* service, grpc::CallbackServerContext* context,
               const dance::v1::WatchRequest& request)
      : writer_(std::make_shared<Writer>(this, Writer::Mode::kLossy, service->options().viewer_queue_frames,
                                         !request.omit_rotations(), service->metrics())),
        metrics_(service->metrics()) {
    absl::Status st = service->CheckAuth(*context);
    if (st.ok()) {
      session_ = service->hub()->Find(request.session_id());
      if (session_ == nullptr) st = absl::NotFoundError(absl::StrCat("no live session '", request.session_id(), "'"));
    }
    if (st.ok()) st = session_->AddViewer(writer_);
    if (!st.ok()) {
      session_.reset();
      metrics_->CountError(st.code());
      writer_->Close(st);
      return;
    }
    metrics_->viewers_started_total.fetch_add(1);
    metrics_->viewers_active.fetch_add(1);
    counted_ = true;
  }

  void IssueWrite(const DanceUpdate* update) { StartWrite(update); }
  void IssueRead() {}
  void IssueFinish(grpc::Status status) { Finish(std::move(status)); }

  void OnWriteDone(bool ok) override { writer_->OnWriteDone(ok); }
  void OnCancel() override { writer_->Close(absl::CancelledError("viewer went away")); }
  void OnDone() override {
    if (session_ != nullptr) session_->RemoveViewer(writer_.get());
    if (counted_) metrics_->viewers_active.fetch_sub(1);
    delete this;
  }

 private:
  using Writer = StreamWriter<WatchReactor>;
  std::shared_ptr<Writer> writer_;
  ServerMetrics* const metrics_;
  std::shared_ptr<LiveSession> session_;
  bool counted_ = false;
};

}  // namespace

DanceServiceImpl::DanceServiceImpl(SessionHub* hub, ServerMetrics* metrics, ServiceOptions options,
                                   EditJobs* edit_jobs)
    : hub_(hub), metrics_(metrics), options_(std::move(options)), edit_jobs_(edit_jobs) {}

absl::Status DanceServiceImpl::CheckAuth(const grpc::CallbackServerContext& context) const {
  if (options_.auth_token.empty()) return absl::OkStatus();
  const auto& md = context.client_metadata();
  auto it = md.find("authorization");
  const std::string want = "Bearer " + options_.auth_token;
  if (it == md.end() || std::string(it->second.data(), it->second.size()) != want) {
    return absl::UnauthenticatedError("missing or wrong bearer token (metadata 'authorization: Bearer ...')");
  }
  return absl::OkStatus();
}

grpc::ServerBidiReactor<PerformRequest, DanceUpdate>* DanceServiceImpl::Perform(
    grpc::CallbackServerContext* context) {
  return new PerformReactor(this, context);
}

grpc::ServerWriteReactor<DanceUpdate>* DanceServiceImpl::Watch(grpc::CallbackServerContext* context,
                                                               const dance::v1::WatchRequest* request) {
  return new WatchReactor(this, context, *request);
}

grpc::ServerUnaryReactor* DanceServiceImpl::ListSessions(grpc::CallbackServerContext* context,
                                                         const dance::v1::ListSessionsRequest* /*request*/,
                                                         dance::v1::ListSessionsResponse* response) {
  grpc::ServerUnaryReactor* reactor = context->DefaultReactor();
  absl::Status auth = CheckAuth(*context);
  if (!auth.ok()) {
    reactor->Finish(ToGrpcStatus(auth));
    return reactor;
  }
  for (const SessionSummary& s : hub_->List()) SummaryToProto(s, response->add_sessions());
  reactor->Finish(grpc::Status::OK);
  return reactor;
}

grpc::ServerUnaryReactor* DanceServiceImpl::GetModelInfo(grpc::CallbackServerContext* context,
                                                         const dance::v1::GetModelInfoRequest* /*request*/,
                                                         dance::v1::ModelInfo* response) {
  grpc::ServerUnaryReactor* reactor = context->DefaultReactor();
  absl::Status auth = CheckAuth(*context);
  if (!auth.ok()) {
    reactor->Finish(ToGrpcStatus(auth));
    return reactor;
  }
  ModelToProto(hub_->model(), response);
  response->set_max_sessions(hub_->options().max_sessions);
  response->set_active_sessions(hub_->active_sessions());
  response->set_max_chunk_samples(options_.limits.max_chunk_samples);
  if (edit_jobs_ != nullptr) EditorToProto(*edit_jobs_, response->mutable_editor());
  reactor->Finish(grpc::Status::OK);
  return reactor;
}

grpc::ServerWriteReactor<dance::v1::EditUpdate>* DanceServiceImpl::Edit(grpc::CallbackServerContext* context,
                                                                        const dance::v1::EditRequest* request) {
  return NewEditReactor(this, context, *request);
}

}  // namespace dance::server
