#include "server/dance_server.h"

#include <fstream>
#include <sstream>
#include <utility>

#include <grpcpp/ext/proto_server_reflection_plugin.h>
#include <grpcpp/health_check_service_interface.h>

#include "absl/strings/str_cat.h"
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
  s->service_ = std::make_unique<DanceServiceImpl>(s->hub_.get(), &s->metrics_, o.service);

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
  builder.RegisterService(s->service_.get());
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
  s->hub_->SetServingListener([raw](bool serving) { raw->SetHealth(serving); });

  if (o.http_port >= 0) {
    o.web.auth_token = o.service.auth_token;
    o.web.limits = o.service.limits;
    o.web.viewer_queue_frames = o.service.viewer_queue_frames;
    o.web.performer_queue_limit = o.service.performer_queue_limit;
    s->web_ = std::make_unique<WebHandler>(s->hub_.get(), &s->metrics_, o.web);
    WebHandler* web = s->web_.get();
    s->http_ = std::make_unique<HttpServer>(
        HttpServerOptions{.bind_address = o.host, .port = o.http_port, .max_connections = o.max_http_connections},
        [web](const HttpRequest& r, HttpConnection& c) { web->Handle(r, c); });
    absl::StatusOr<int> hp = s->http_->Start();
    if (!hp.ok()) return hp.status();
    s->http_port_ = *hp;
  }
  Log(LogLevel::kInfo, "server_start",
      {{"grpc_port", s->port_}, {"http_port", s->http_port_}, {"model", s->hub_->model().model_id},
       {"max_sessions", o.hub.max_sessions}, {"scheduler_threads", o.hub.scheduler_threads},
       {"tls", !o.tls_cert_file.empty()},
       {"auth", !o.service.auth_token.empty()}});
  return s;
}

DanceServer::~DanceServer() { Shutdown(); }

void DanceServer::SetHealth(bool serving) {
  if (grpc_ == nullptr) return;
  grpc::HealthCheckServiceInterface* health = grpc_->GetHealthCheckService();
  if (health == nullptr) return;
  health->SetServingStatus(serving);  // all services, including ""
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
  if (grpc_) grpc_->Shutdown(std::chrono::system_clock::now() + std::chrono::seconds(5));
  Log(LogLevel::kInfo, "server_stop", {{"frames_total", metrics_.frames_total.load()}});
}

}  // namespace dance::server
