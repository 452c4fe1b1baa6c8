// ClusterDanceService: dance.v1.DanceService for a server in a cluster. It wraps the single-server
// DanceServiceImpl and adds what a cluster needs, so a client may reach any server (through the proxy):
//   Perform, GetModelInfo  as DanceServiceImpl (a performer dances on the server it reached)
//   Watch                  a local session: as DanceServiceImpl. Another server's: found in the registry and
//                          relayed: this server opens Watch on the owner and forwards every update as it
//                          arrives (one update in flight: the owner's per-viewer queue drops frames for a
//                          slow viewer, as it does for a direct one). NOT_FOUND when no server holds it.
//   ListSessions           this server's sessions plus every live peer's, newest first (peers asked in
//                          parallel, 2 s deadline; a peer that does not answer is left out and logged)
// Calls between servers carry the metadata "x-dance-peer: 1": a server answers them from its own sessions
// only, so a stale registry entry can never make a relay loop. The caller's "authorization" is forwarded.
//
// Usage (dance_server.cc):
//   DanceServiceImpl local(&hub, &metrics, options);
//   ClusterDanceService service(&local, &registry);
//   builder.RegisterService(&service);
//
// Thread safety: as DanceServiceImpl; reactors never block (lookups run on the registry's thread, peers
// are called with gRPC's callback API). Must outlive the grpc::Server; `local` and `registry` outlive it.
#ifndef DANCE_SERVER_CLUSTER_CLUSTER_SERVICE_H_
#define DANCE_SERVER_CLUSTER_CLUSTER_SERVICE_H_

#include <memory>
#include <string>

#include <grpcpp/grpcpp.h>

#include "absl/base/thread_annotations.h"
#include "absl/container/flat_hash_map.h"
#include "absl/synchronization/mutex.h"
#include "dance/v1/dance.grpc.pb.h"
#include "server/cluster/registry.h"
#include "server/grpc/dance_service.h"

namespace dance::server {

inline constexpr char kPeerCallKey[] = "x-dance-peer";

class ClusterDanceService final : public dance::v1::DanceService::CallbackService {
 public:
  ClusterDanceService(DanceServiceImpl* local, ClusterRegistry* registry, int max_message_bytes);

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
  // Edits run on the server the client reached (they need no session).
  grpc::ServerWriteReactor<dance::v1::EditUpdate>* Edit(grpc::CallbackServerContext* context,
                                                        const dance::v1::EditRequest* request) override;

  // A stub to a peer's gRPC address; channels are made once per address and kept.
  std::shared_ptr<dance::v1::DanceService::Stub> PeerStub(const std::string& address);
  DanceServiceImpl* local() const { return local_; }
  ClusterRegistry* registry() const { return registry_; }

 private:
  DanceServiceImpl* const local_;
  ClusterRegistry* const registry_;
  const int max_message_bytes_;
  absl::Mutex mu_;
  absl::flat_hash_map<std::string, std::shared_ptr<dance::v1::DanceService::Stub>> stubs_ ABSL_GUARDED_BY(mu_);
};

// True if the call came from another server of the cluster (metadata x-dance-peer).
bool IsPeerCall(const grpc::CallbackServerContext& context);

}  // namespace dance::server

#endif  // DANCE_SERVER_CLUSTER_CLUSTER_SERVICE_H_
