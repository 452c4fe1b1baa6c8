// Conversions between the wire (dance.v1 protos, WebSocket JSON) and the server's engine-facing types,
// with the protocol's validation rules. Pure functions; thread-safe.
#ifndef DANCE_SERVER_GRPC_CONVERT_H_
#define DANCE_SERVER_GRPC_CONVERT_H_

#include <optional>
#include <string>

#include "absl/status/statusor.h"
#include "dance/v1/dance.pb.h"
#include "nlohmann/json.hpp"
#include "server/core/engine_port.h"
#include "server/core/live_session.h"

namespace dance::server {

struct StreamLimits {
  int min_sample_rate_hz = 8000;
  int max_sample_rate_hz = 96000;
  int max_channels = 8;
  int max_chunk_samples = 48000;  // sample frames per chunk
};

struct ValidatedHeader {
  StreamConfig config;
  PcmFormat format = PcmFormat::kF32Le;
  std::string client_name;
  bool omit_rotations = false;
};

// INVALID_ARGUMENT with a message naming the field for any out-of-range value or unknown style.
absl::StatusOr<ValidatedHeader> ValidateHeader(const dance::v1::StreamHeader& header, const ModelDescription& model,
                                               const StreamLimits& limits);
absl::StatusOr<StyleMix> StyleFromProto(const google::protobuf::RepeatedPtrField<dance::v1::StyleWeight>& style,
                                        const ModelDescription& model);
absl::StatusOr<SamplingConfig> SamplingFromProto(const dance::v1::Sampling& sampling);
// Checks a chunk's size against the limits and whole-sample-frame alignment.
absl::Status ValidateChunk(size_t pcm_bytes, const ValidatedHeader& header, const StreamLimits& limits);

// WebSocket JSON -> proto: {"type":"start", ...} to a StreamHeader, {"type":"control", ...} to a Control.
absl::StatusOr<dance::v1::StreamHeader> HeaderFromJson(const nlohmann::json& start);
absl::StatusOr<dance::v1::Control> ControlFromJson(const nlohmann::json& control);
// Proto -> WebSocket JSON text (docs/protocol.md section 3).
std::string UpdateToJson(const dance::v1::DanceUpdate& update);
nlohmann::json ModelToJson(const ModelDescription& model);
nlohmann::json SummaryToJson(const dance::v1::SessionSummary& summary);

}  // namespace dance::server

#endif  // DANCE_SERVER_GRPC_CONVERT_H_
