#include "server/dance_server.h"

#include <fstream>
#include <sstream>
#include <utility>

#include <grpcpp/ext/proto_server_reflection_plugin.h>
#include <grpcpp/health_check_service_interface.h>

#include "absl/strings/str_cat.h"
#include "server/cluster/http_relay.h"
#include "server/log.h"

namespace dance::server {
namespace {

absl::StatusOr<std::string> ReadFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError(absl::StrCat("cannot read ", path));
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

}  // namespace

absl::StatusOr<std::unique_ptr<DanceServer>> DanceServer::Start(std::unique_ptr<EngineBackend> backend,
                                                                DanceServerOptions options) {
  std::unique_ptr<DanceServer> s(new DanceServer());
  s->options_ = std::move(options);
  DanceServerOptions& o = s->options_;
  s->backend_ = std::move(backend);
  s->hub_ = std::make_unique<SessionHub>(s->backend_.get(), o.hub, &s->metrics_);
  if (o.editor != nullptr) s->edit_jobs_ = std::make_unique<EditJobs>(o.editor.get(), o.edit);
  s->service_ = std::make_unique<DanceServiceImpl>(s->hub_.get(), &s->metrics_, o.service, s->edit_jobs_.get());
  grpc::Service* service = s->service_.get();
  if (!o.cluster.store_address.empty()) {
    SessionHub* hub = s->hub_.get();
    s->registry_ = std::make_unique<ClusterRegistry>(o.cluster, [hub] {
      std::vector<std::string> ids;
      for (const SessionSummary& sum : hub->List()) ids.push_back(sum.session_id);
      return ids;
    });
    s->cluster_service_ =
        std::make_unique<ClusterDanceService>(s->service_.get(), s->registry_.get(), o.max_message_bytes);
    service = s->cluster_service_.get();
  }

  grpc::EnableDefaultHealthCheckService(true);
  grpc::reflection::InitProtoReflectionServerBuilderPlugin();
  grpc::ServerBuilder builder;
  std::shared_ptr<grpc::ServerCredentials> creds = grpc::InsecureServerCredentials();
  if (!o.tls_cert_file.empty() || !o.tls_key_file.empty()) {
    absl::StatusOr<std::string> cert = ReadFile(o.tls_cert_file);
    if (!cert.ok()) return cert.status();
    absl::StatusOr<std::string> key = ReadFile(o.tls_key_file);
    if (!key.ok()) return key.status();
    grpc::SslServerCredentialsOptions ssl;
    ssl.pem_key_cert_pairs.push_back({*key, *cert});
    creds = grpc::SslServerCredentials(ssl);
  }
  builder.AddListeningPort(absl::StrCat(o.host, ":", o.port), creds, &s->port_);
  builder.RegisterService(service);
  builder.SetMaxReceiveMessageSize(o.max_message_bytes);
  builder.SetMaxSendMessageSize(o.max_message_bytes);
  builder.AddChannelArgument(GRPC_ARG_KEEPALIVE_TIME_MS, static_cast<int>(absl::ToInt64Milliseconds(o.keepalive_time)));
  builder.AddChannelArgument(GRPC_ARG_KEEPALIVE_TIMEOUT_MS,
                             static_cast<int>(absl::ToInt64Milliseconds(o.keepalive_timeout)));
  builder.AddChannelArgument(GRPC_ARG_KEEPALIVE_PERMIT_WITHOUT_CALLS, 1);
  builder.AddChannelArgument(GRPC_ARG_HTTP2_MIN_RECV_PING_INTERVAL_WITHOUT_DATA_MS, 5000);
  builder.AddChannelArgument(GRPC_ARG_HTTP2_MAX_PING_STRIKES, 0);
  s->grpc_ = builder.BuildAndStart();
  if (s->grpc_ == nullptr || s->port_ == 0) {
    return absl::UnavailableError(absl::StrCat("cannot listen for gRPC on ", o.host, ":", o.port));
  }
  DanceServer* raw = s.get();
  s->hub_->SetServingListener([raw](bool) {
    raw->SetHealth();
    if (raw->registry_) raw->registry_->SessionsChanged();  // a session started or ended: mirror it now
  });

  if (o.http_port >= 0) {
    o.web.auth_token = o.service.auth_token;
    o.web.limits = o.service.limits;
    o.web.viewer_queue_frames = o.service.viewer_queue_frames;
    o.web.performer_queue_limit = o.service.performer_queue_limit;
    s->web_ = std::make_unique<WebHandler>(s->hub_.get(), &s->metrics_, o.web, s->edit_jobs_.get());
    s->http_ = std::make_unique<HttpServer>(
        HttpServerOptions{.bind_address = o.host, .port = o.http_port, .max_connections = o.max_http_connections},
        [raw](const HttpRequest& r, HttpConnection& c) { raw->HandleHttp(r, c); });
    absl::StatusOr<int> hp = s->http_->Start();
    if (!hp.ok()) return hp.status();
    s->http_port_ = *hp;
  }
  if (s->registry_) s->registry_->Start(s->port_, s->http_port_);
  Log(LogLevel::kInfo, "server_start",
      {{"grpc_port", s->port_}, {"http_port", s->http_port_}, {"model", s->hub_->model().model_id},
       {"max_sessions", o.hub.max_sessions}, {"scheduler_threads", o.hub.scheduler_threads},
       {"tls", !o.tls_cert_file.empty()},
       {"auth", !o.service.auth_token.empty()},
       {"cluster_store", o.cluster.store_address},
       {"server_id", s->registry_ ? s->registry_->self().id : ""}});
  return s;
}

DanceServer::~DanceServer() { Shutdown(); }

void DanceServer::HandleHttp(const HttpRequest& request, HttpConnection& connection) {
  // A browser watching a session another server holds: hand the socket to that server.
  if (registry_ != nullptr && request.path == "/ws/watch" && request.Header(kPeerHeader).empty()) {
    auto it = request.query.find("session");
    if (it != request.query.end() && hub_->Find(it->second) == nullptr) {
      absl::StatusOr<Peer> owner =
          registry_->LookupBlocking(it->second, absl::Now() + registry_->options().lookup_wait);
      if (owner.ok() && owner->id != registry_->self().id && !owner->http_address.empty()) {
        absl::Status relayed = RelayHttpUpgrade(request, connection.fd(), owner->http_address);
        if (!relayed.ok()) connection.RespondJsonError(502, relayed.message());
        return;
      }
      if (absl::IsUnavailable(owner.status())) {
        connection.RespondJsonError(503, owner.status().message());
        return;
      }
    }
  }
  web_->Handle(request, connection);  // everything else, and a session no server holds (404)
}

void DanceServer::SetHealth() {
  if (grpc_ == nullptr) return;
  grpc::HealthCheckServiceInterface* health = grpc_->GetHealthCheckService();
  if (health == nullptr) return;
  // Listeners run on whichever thread changed the hub, so two calls may race; reading serving() under
  // health_mu_ (not taking the listener's argument) makes the last call write the latest state.
  absl::MutexLock lock(&health_mu_);
  const bool serving = hub_->serving();
  // The default service knows only "" until a name is set explicitly; probes ask for the service by name
  // (grpc-health-probe -service=dance.v1.DanceService, Kubernetes' grpc probe with `service:`).
  health->SetServingStatus(serving);  // every name set so far, including ""
  health->SetServingStatus(dance::v1::DanceService::service_full_name(), serving);
}

bool DanceServer::Drain(absl::Duration timeout) {
  hub_->StartDrain();
  const bool clean = hub_->WaitUntilEmpty(timeout);
  Log(LogLevel::kInfo, "drain_done", {{"clean", clean}, {"sessions_left", hub_->active_sessions()}});
  return clean;
}

void DanceServer::Shutdown() {
  {
    absl::MutexLock lock(&mu_);
    if (shut_down_) return;
    shut_down_ = true;
  }
  if (hub_) hub_->StartDrain();
  if (http_) http_->Stop();
  // Ends live sessions first (their calls finish with UNAVAILABLE), then the gRPC server.
  if (hub_) hub_->Shutdown();
  if (edit_jobs_) edit_jobs_->Shutdown();  // queued edits end UNAVAILABLE, running ones stop at their next step
  if (grpc_) grpc_->Shutdown(std::chrono::system_clock::now() + std::chrono::seconds(5));
  if (registry_) registry_->Stop();  // after gRPC: relays still in flight use its lookups
  Log(LogLevel::kInfo, "server_stop", {{"frames_total", metrics_.frames_total.load()}});
}

}  // namespace dance::server
