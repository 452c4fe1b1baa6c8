// DanceServer: the whole service in one object: engine backend, the core's session hub (admission +
// schedulers), and its two transports: the gRPC server (DanceService, health, reflection) and the
// HTTP/WebSocket server; in a cluster (options.cluster) also the session registry and the services that
// reach sessions on other servers. main.cc maps flags to DanceServerOptions; integration tests start one on
// port 0.
//
// Usage:
//   ASSIGN_OR_RETURN(auto backend, LoadEngineBackend("models/test-tiny.dncw"));
//   DanceServerOptions o; o.port = 0; o.http_port = 0;
//   ASSIGN_OR_RETURN(std::unique_ptr<DanceServer> server, DanceServer::Start(std::move(backend), o));
//   Connect to absl::StrCat("localhost:", server->port()); ...
//   server->Drain(absl::Seconds(30));    // SIGTERM path: refuse new sessions, let live ones finish
//   server->Shutdown();                  // idempotent; also run by the destructor
//
// Thread safety: Drain and Shutdown may be called from any thread (once each is enough).
#ifndef DANCE_SERVER_DANCE_SERVER_H_
#define DANCE_SERVER_DANCE_SERVER_H_

#include <memory>
#include <string>

#include <grpcpp/grpcpp.h>

#include "absl/status/statusor.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"
#include "server/cluster/cluster_service.h"
#include "server/cluster/registry.h"
#include "server/core/edit_jobs.h"
#include "server/core/editor_port.h"
#include "server/core/engine_port.h"
#include "server/core/metrics.h"
#include "server/core/session_hub.h"
#include "server/grpc/dance_service.h"
#include "server/web/http_server.h"
#include "server/web/web_handler.h"

namespace dance::server {

struct DanceServerOptions {
  std::string host = "0.0.0.0";
  int port = 50051;                    // gRPC; 0 = pick a free port
  int http_port = 8080;                // HTTP/WebSocket; 0 = pick a free port, -1 = no HTTP server
  HubOptions hub;
  ServiceOptions service;              // auth_token and limits are copied into `web` by Start
  WebOptions web;
  int max_http_connections = 256;
  int max_message_bytes = 4 << 20;     // largest gRPC message accepted
  absl::Duration keepalive_time = absl::Seconds(30);
  absl::Duration keepalive_timeout = absl::Seconds(10);
  std::string tls_cert_file;           // both set = TLS on the gRPC port
  std::string tls_key_file;
  // cluster.store_address set = one of several servers: sessions registered in the store, Watch and
  // ListSessions reach sessions on every server, /ws/watch relayed (docs/server.md, "Several servers").
  ClusterOptions cluster;
  // Set = the Edit RPC with this diffusion editor (LoadEditorBackend) on edit.workers threads.
  std::shared_ptr<const EditorBackend> editor;
  EditJobsOptions edit;
};

class DanceServer {
 public:
  static absl::StatusOr<std::unique_ptr<DanceServer>> Start(std::unique_ptr<EngineBackend> backend,
                                                            DanceServerOptions options);
  ~DanceServer();

  int port() const { return port_; }
  int http_port() const { return http_port_; }
  SessionHub& hub() { return *hub_; }
  ServerMetrics& metrics() { return metrics_; }
  ClusterRegistry* registry() { return registry_.get(); }  // null unless options.cluster.store_address

  // Marks the server NOT_SERVING, refuses new sessions (UNAVAILABLE) and waits up to `timeout` for live
  // sessions to end. Returns true if all ended in time. Shutdown() afterwards ends the rest.
  bool Drain(absl::Duration timeout);
  void Shutdown();

 private:
  DanceServer() = default;
  void SetHealth();
  void HandleHttp(const HttpRequest& request, HttpConnection& connection);  // grpc.health.v1 for "" and dance.v1.DanceService from hub_->serving()

  DanceServerOptions options_;
  ServerMetrics metrics_;
  std::unique_ptr<EngineBackend> backend_;
  std::unique_ptr<SessionHub> hub_;
  std::unique_ptr<EditJobs> edit_jobs_;                   // null without an editor
  std::unique_ptr<DanceServiceImpl> service_;
  std::unique_ptr<ClusterRegistry> registry_;             // null unless options_.cluster.store_address
  std::unique_ptr<ClusterDanceService> cluster_service_;  // wraps service_ when registry_ is set
  std::unique_ptr<WebHandler> web_;
  std::unique_ptr<grpc::Server> grpc_;
  std::unique_ptr<HttpServer> http_;
  int port_ = 0;
  int http_port_ = -1;
  absl::Mutex health_mu_;
  absl::Mutex mu_;
  bool shut_down_ ABSL_GUARDED_BY(mu_) = false;
};

}  // namespace dance::server

#endif  // DANCE_SERVER_DANCE_SERVER_H_
