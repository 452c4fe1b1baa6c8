// The Edit call (dance.v1.DanceService.Edit): validates an EditRequest, submits it to the server's
// EditJobs and streams the job's queue position, progress and result (docs/protocol.md, docs/diffusion.md).
//
// Usage (dance_service.cc):
//   return NewEditReactor(service, context, *request);
//
// Thread safety: job events arrive on worker threads; the reactor serialises its writes (one in flight,
// progress coalesced to the newest) and issues Finish exactly once, never during a write.
#ifndef DANCE_SERVER_GRPC_EDIT_REACTOR_H_
#define DANCE_SERVER_GRPC_EDIT_REACTOR_H_

#include <grpcpp/grpcpp.h>

#include "absl/status/statusor.h"
#include "dance/v1/dance.pb.h"
#include "server/core/edit_jobs.h"

namespace dance::server {

class DanceServiceImpl;

grpc::ServerWriteReactor<dance::v1::EditUpdate>* NewEditReactor(DanceServiceImpl* service,
                                                                grpc::CallbackServerContext* context,
                                                                const dance::v1::EditRequest& request);

// The request as the core's EditConfig: INVALID_ARGUMENT naming the field (steps outside 0..1000, guidance
// outside [0, 100], overlap outside [0, window), no audio, a client name over 64 bytes, controls of a bad
// shape).
absl::StatusOr<EditConfig> EditConfigFromProto(const dance::v1::EditRequest& request, const EditorDescription& editor);
void EditResultToProto(const EditOutput& out, const EditorDescription& editor, bool with_rotations, double compute_s,
                       dance::v1::EditResult* result);
void EditorToProto(const EditJobs& jobs, dance::v1::EditorInfo* out);

}  // namespace dance::server

#endif  // DANCE_SERVER_GRPC_EDIT_REACTOR_H_
