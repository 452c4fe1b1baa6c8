// The gRPC transport's encoding: conversions between the dance.v1 protos and the core's types
// (server/core/). Requests come in as StreamRequest / ControlRequest and are validated by the core's rules
// (stream_request.h); updates, session summaries and the model go out as protos. The one place that maps
// between dance.v1 messages and the core. Pure functions; thread-safe.
//
// Usage:
//   ASSIGN_OR_RETURN(ValidatedStream v, ValidateHeader(request.header(), hub.model(), limits));
//   const dance::v1::DanceUpdate& wire = UpdateToProto(*update, /*with_rotations=*/true);
#ifndef DANCE_SERVER_GRPC_CONVERT_H_
#define DANCE_SERVER_GRPC_CONVERT_H_

#include "absl/status/statusor.h"
#include "dance/v1/dance.pb.h"
#include "server/core/engine_port.h"
#include "server/core/live_session.h"
#include "server/core/stream_request.h"
#include "server/core/update.h"

namespace dance::server {

// ---- in ----
StyleMix StyleFromProto(const google::protobuf::RepeatedPtrField<dance::v1::StyleWeight>& style);
SamplingRequest SamplingFromProto(const dance::v1::Sampling& sampling);
StreamRequest StreamRequestFromProto(const dance::v1::StreamHeader& header);
ControlRequest ControlRequestFromProto(const dance::v1::Control& control);
ControlSpec ControlsFromProto(const dance::v1::MotionControls& controls);
SteerTarget SteerFromProto(const dance::v1::SteerTarget& steer);
PoseRequest PoseFromProto(const dance::v1::PoseInput& pose);
// ValidateStream(StreamRequestFromProto(header), ...): INVALID_ARGUMENT naming the field.
absl::StatusOr<ValidatedStream> ValidateHeader(const dance::v1::StreamHeader& header, const ModelDescription& model,
                                               const StreamLimits& limits);

// ---- out ----
// The update as a DanceUpdate: built on first use and kept on the update (update.h), so every gRPC call
// that sends it shares one message; valid while the update lives. Without rotations a frame's rotations
// are left empty (StreamHeader.omit_rotations); other kinds are the same either way.
const dance::v1::DanceUpdate& UpdateToProto(const Update& update, bool with_rotations);
void SummaryToProto(const SessionSummary& summary, dance::v1::SessionSummary* out);
void SkeletonToProto(const ModelDescription& model, dance::v1::Skeleton* out);
// Everything ModelInfo says about the model (not the server's limits or load).
void ModelToProto(const ModelDescription& model, dance::v1::ModelInfo* out);

}  // namespace dance::server

#endif  // DANCE_SERVER_GRPC_CONVERT_H_
