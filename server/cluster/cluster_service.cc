#include "server/cluster/cluster_service.h"

#include <algorithm>
#include <atomic>
#include <utility>
#include <vector>

#include "absl/container/flat_hash_set.h"
#include "absl/strings/str_cat.h"
#include "server/grpc/convert.h"
#include "server/log.h"

namespace dance::server {
namespace {

using dance::v1::DanceUpdate;

grpc::Status ToGrpc(const absl::Status& s) {
  if (s.ok()) return grpc::Status::OK;
  return grpc::Status(static_cast<grpc::StatusCode>(s.code()), std::string(s.message()));
}

// Copies what a peer needs from the caller's metadata and marks the call as a peer call.
void PreparePeerContext(const grpc::CallbackServerContext& from, grpc::ClientContext* to) {
  const auto& md = from.client_metadata();
  auto auth = md.find("authorization");
  if (auth != md.end()) to->AddMetadata("authorization", std::string(auth->second.data(), auth->second.size()));
  to->AddMetadata(kPeerCallKey, "1");
}

// A Watch of a session held by another server: look the owner up, open Watch there, forward each update.
// Lifetime: two references, the server call's (released in OnDone) and the upstream call's (released
// when it ends, or at once if it never starts); the last one deletes the relay.
class WatchRelay final : public grpc::ServerWriteReactor<DanceUpdate> {
 public:
  WatchRelay(ClusterDanceService* service, grpc::CallbackServerContext* context, const dance::v1::WatchRequest& request)
      : service_(service), context_(context), request_(request), upstream_(this) {
    ClusterRegistry* registry = service_->registry();
    registry->Lookup(request_.session_id(), absl::Now() + registry->options().lookup_wait,
                     [this](absl::StatusOr<Peer> owner) { OnLookup(std::move(owner)); });
  }

  void OnWriteDone(bool ok) override {
    if (!ok) {
      Cancel();
      return;
    }
    upstream_.StartRead(&update_);
  }
  void OnCancel() override { Cancel(); }
  void OnDone() override { Release(); }

 private:
  class Upstream final : public grpc::ClientReadReactor<DanceUpdate> {
   public:
    explicit Upstream(WatchRelay* relay) : relay_(relay) {}
    void OnReadDone(bool ok) override {
      if (ok) relay_->StartWrite(&relay_->update_);  // else: the call's status follows in OnDone
    }
    void OnDone(const grpc::Status& status) override { relay_->OnUpstreamDone(status); }

   private:
    WatchRelay* const relay_;
  };

  void OnLookup(absl::StatusOr<Peer> owner) {
    if (owner.ok() && owner->id == service_->registry()->self().id) {
      owner = absl::NotFoundError(absl::StrCat("no live session ", request_.session_id()));  // ended meanwhile
    }
    if (!owner.ok()) {
      Finish(ToGrpc(owner.status()));
      Release();  // the upstream call never starts
      return;
    }
    {
      absl::MutexLock lock(&mu_);
      if (cancelled_) {
        Finish(grpc::Status::CANCELLED);
        Release();
        return;
      }
      // Inherits the caller's deadline and cancellation.
      client_context_ = grpc::ClientContext::FromCallbackServerContext(*context_);
      PreparePeerContext(*context_, client_context_.get());
      started_ = true;
    }
    Log(LogLevel::kDebug, "watch_relay", {{"session", request_.session_id()}, {"owner", owner->id}});
    stub_ = service_->PeerStub(owner->grpc_address);
    stub_->async()->Watch(client_context_.get(), &request_, &upstream_);
    upstream_.StartRead(&update_);
    upstream_.StartCall();
  }

  void OnUpstreamDone(const grpc::Status& status) {
    Finish(status);
    Release();
  }

  void Cancel() {
    absl::MutexLock lock(&mu_);
    cancelled_ = true;
    if (started_) client_context_->TryCancel();
  }

  void Release() {
    if (refs_.fetch_sub(1) == 1) delete this;
  }

  ClusterDanceService* const service_;
  grpc::CallbackServerContext* const context_;
  const dance::v1::WatchRequest request_;
  std::shared_ptr<dance::v1::DanceService::Stub> stub_;
  Upstream upstream_;
  DanceUpdate update_;  // read from upstream, then written downstream; never both at once
  std::atomic<int> refs_{2};
  absl::Mutex mu_;
  bool cancelled_ ABSL_GUARDED_BY(mu_) = false;
  bool started_ ABSL_GUARDED_BY(mu_) = false;
  std::unique_ptr<grpc::ClientContext> client_context_ ABSL_GUARDED_BY(mu_);
};

// ListSessions across the cluster: this server's sessions, then each peer's, merged when the last answers.
class SessionsGather {
 public:
  SessionsGather(grpc::ServerUnaryReactor* reactor, dance::v1::ListSessionsResponse* response, int pending)
      : reactor_(reactor), response_(response), pending_(pending) {}

  struct PeerCall {
    grpc::ClientContext context;
    dance::v1::ListSessionsRequest request;
    dance::v1::ListSessionsResponse response;
    std::string peer;
  };

  void Add(const dance::v1::ListSessionsResponse& part) {
    absl::MutexLock lock(&mu_);
    for (const auto& s : part.sessions()) {
      if (seen_.insert(s.session_id()).second) *response_->add_sessions() = s;
    }
  }

  // Called once per peer; the last one finishes the call (and deletes this).
  void Done() {
    {
      absl::MutexLock lock(&mu_);
      if (--pending_ > 0) return;
    }
    auto* sessions = response_->mutable_sessions();
    std::sort(sessions->begin(), sessions->end(),
              [](const dance::v1::SessionSummary& a, const dance::v1::SessionSummary& b) {
                return a.started_unix_ms() != b.started_unix_ms() ? a.started_unix_ms() > b.started_unix_ms()
                                                                  : a.session_id() < b.session_id();
              });
    reactor_->Finish(grpc::Status::OK);
    delete this;
  }

 private:
  grpc::ServerUnaryReactor* const reactor_;
  dance::v1::ListSessionsResponse* const response_;
  absl::Mutex mu_;
  int pending_ ABSL_GUARDED_BY(mu_);
  absl::flat_hash_set<std::string> seen_ ABSL_GUARDED_BY(mu_);
};

}  // namespace

bool IsPeerCall(const grpc::CallbackServerContext& context) {
  return context.client_metadata().count(kPeerCallKey) > 0;
}

ClusterDanceService::ClusterDanceService(DanceServiceImpl* local, ClusterRegistry* registry, int max_message_bytes)
    : local_(local), registry_(registry), max_message_bytes_(max_message_bytes) {}

std::shared_ptr<dance::v1::DanceService::Stub> ClusterDanceService::PeerStub(const std::string& address) {
  absl::MutexLock lock(&mu_);
  auto& stub = stubs_[address];
  if (stub == nullptr) {
    // Servers talk to each other in the clear inside the cluster's network (docs/server.md).
    grpc::ChannelArguments args;
    args.SetMaxReceiveMessageSize(max_message_bytes_);
    stub = dance::v1::DanceService::NewStub(
        grpc::CreateCustomChannel(address, grpc::InsecureChannelCredentials(), args));
  }
  return stub;
}

grpc::ServerBidiReactor<dance::v1::PerformRequest, DanceUpdate>* ClusterDanceService::Perform(
    grpc::CallbackServerContext* context) {
  return local_->Perform(context);
}

grpc::ServerUnaryReactor* ClusterDanceService::GetModelInfo(grpc::CallbackServerContext* context,
                                                            const dance::v1::GetModelInfoRequest* request,
                                                            dance::v1::ModelInfo* response) {
  return local_->GetModelInfo(context, request, response);
}

grpc::ServerWriteReactor<dance::v1::EditUpdate>* ClusterDanceService::Edit(grpc::CallbackServerContext* context,
                                                                           const dance::v1::EditRequest* request) {
  return local_->Edit(context, request);
}

grpc::ServerWriteReactor<DanceUpdate>* ClusterDanceService::Watch(grpc::CallbackServerContext* context,
                                                                  const dance::v1::WatchRequest* request) {
  if (IsPeerCall(*context) || local_->hub()->Find(request->session_id()) != nullptr ||
      !local_->CheckAuth(*context).ok()) {
    return local_->Watch(context, request);  // also answers a bad token (UNAUTHENTICATED) as usual
  }
  return new WatchRelay(this, context, *request);
}

grpc::ServerUnaryReactor* ClusterDanceService::ListSessions(grpc::CallbackServerContext* context,
                                                            const dance::v1::ListSessionsRequest* request,
                                                            dance::v1::ListSessionsResponse* response) {
  if (IsPeerCall(*context) || !local_->CheckAuth(*context).ok()) {
    return local_->ListSessions(context, request, response);
  }
  grpc::ServerUnaryReactor* reactor = context->DefaultReactor();
  const std::vector<Peer> peers = registry_->Peers();
  // The local part: one more pending "peer" so the gather cannot finish before it is in.
  auto* gather = new SessionsGather(reactor, response, static_cast<int>(peers.size()) + 1);
  dance::v1::ListSessionsResponse mine;
  for (const SessionSummary& s : local_->hub()->List()) SummaryToProto(s, mine.add_sessions());
  gather->Add(mine);
  for (const Peer& p : peers) {
    auto call = std::make_shared<SessionsGather::PeerCall>();
    call->peer = p.id;
    PreparePeerContext(*context, &call->context);
    call->context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(2));
    PeerStub(p.grpc_address)
        ->async()
        ->ListSessions(&call->context, &call->request, &call->response, [gather, call](grpc::Status s) {
          if (s.ok()) {
            gather->Add(call->response);
          } else {
            Log(LogLevel::kWarning, "peer_list_failed", {{"peer", call->peer}, {"error", s.error_message()}});
          }
          gather->Done();
        });
  }
  gather->Done();  // the local part
  return reactor;
}

}  // namespace dance::server
