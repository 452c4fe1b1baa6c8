// DanceServiceImpl: the gRPC callback service for dance.v1.DanceService.
//
// The gRPC transport over the core (server/core/). Perform and Watch are reactors that never block:
// Perform decodes and validates each message (convert.h, then the core's rules) and queues it on its
// LiveSession (the scheduler thread does the engine work); outgoing updates go through a StreamWriter,
// which sends them as protos. Unary calls answer inline from the hub's registry.
//
// Usage (see dance_server.cc):
//   DanceServiceImpl service(&hub, &metrics, options);
//   builder.RegisterService(&service);
//
// Thread safety: gRPC calls the service from its own threads; the service itself is stateless beyond the
// hub and metrics, which are thread-safe. It must outlive the grpc::Server.
#ifndef DANCE_SERVER_GRPC_DANCE_SERVICE_H_
#define DANCE_SERVER_GRPC_DANCE_SERVICE_H_

#include <string>

#include <grpcpp/grpcpp.h>

#include "absl/status/status.h"
#include "absl/time/time.h"
#include "dance/v1/dance.grpc.pb.h"
#include "server/core/edit_jobs.h"
#include "server/core/metrics.h"
#include "server/core/session_hub.h"
#include "server/core/stream_request.h"

namespace dance::server {

struct ServiceOptions {
  std::string auth_token;              // empty = no authentication
  StreamLimits limits;
  size_t performer_queue_limit = 1024; // updates queued for a performer before RESOURCE_EXHAUSTED
  size_t viewer_queue_frames = 8;      // frames queued for a viewer before old ones are dropped
  // After a session ends OK its Perform call finishes once the client half-closes, or after this long.
  absl::Duration half_close_grace = absl::Seconds(5);
};

class DanceServiceImpl final : public dance::v1::DanceService::CallbackService {
 public:
  // `edit_jobs` may be null (no editor: Edit answers UNIMPLEMENTED).
  DanceServiceImpl(SessionHub* hub, ServerMetrics* metrics, ServiceOptions options, EditJobs* edit_jobs = nullptr);

  grpc::ServerBidiReactor<dance::v1::PerformRequest, dance::v1::DanceUpdate>* Perform(
      grpc::CallbackServerContext* context) override;
  grpc::ServerWriteReactor<dance::v1::DanceUpdate>* Watch(grpc::CallbackServerContext* context,
                                                          const dance::v1::WatchRequest* request) override;
  grpc::ServerUnaryReactor* ListSessions(grpc::CallbackServerContext* context,
                                         const dance::v1::ListSessionsRequest* request,
                                         dance::v1::ListSessionsResponse* response) override;
  grpc::ServerUnaryReactor* GetModelInfo(grpc::CallbackServerContext* context,
                                         const dance::v1::GetModelInfoRequest* request,
                                         dance::v1::ModelInfo* response) override;
  grpc::ServerWriteReactor<dance::v1::EditUpdate>* Edit(grpc::CallbackServerContext* context,
                                                        const dance::v1::EditRequest* request) override;

  // OK, or UNAUTHENTICATED when a token is configured and the call lacks "authorization: Bearer <token>".
  absl::Status CheckAuth(const grpc::CallbackServerContext& context) const;

  SessionHub* hub() const { return hub_; }
  ServerMetrics* metrics() const { return metrics_; }
  const ServiceOptions& options() const { return options_; }
  EditJobs* edit_jobs() const { return edit_jobs_; }

 private:
  SessionHub* const hub_;
  ServerMetrics* const metrics_;
  const ServiceOptions options_;
  EditJobs* const edit_jobs_;
};

}  // namespace dance::server

#endif  // DANCE_SERVER_GRPC_DANCE_SERVICE_H_
