// What a client asks for, in plain C++ (a transport decodes its wire form into these), and the protocol's
// validation rules, written once for every transport: ranges, formats, known styles, the limits of this
// server. Pure functions; thread-safe.
//
// Usage (a transport):
//   StreamRequest r = ...decoded from a StreamHeader or a {"type": "start"} message...;
//   ASSIGN_OR_RETURN(ValidatedStream v, ValidateStream(r, hub.model(), limits));
//   ASSIGN_OR_RETURN(std::shared_ptr<LiveSession> s, hub.Admit(v.config, v.format, v.client_name));
//   RETURN_IF_ERROR(ValidateChunk(pcm.size(), v, limits));
//
// Errors: INVALID_ARGUMENT with a message naming the field (its proto name, e.g. "sample_rate_hz",
// "sampling.top_p"), the first bad field in the order the fields are listed here.
#ifndef DANCE_SERVER_CORE_STREAM_REQUEST_H_
#define DANCE_SERVER_CORE_STREAM_REQUEST_H_

#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "server/core/engine_port.h"

namespace dance::server {

enum class PcmFormat { kF32Le, kS16Le };

inline int BytesPerSample(PcmFormat f) { return f == PcmFormat::kF32Le ? 4 : 2; }

// The most poses one control may carry (10 minutes at 30 fps; a longer given motion goes in a file).
inline constexpr size_t kMaxControlFrames = 30 * 600;

struct StreamLimits {
  int min_sample_rate_hz = 8000;
  int max_sample_rate_hz = 96000;
  int max_channels = 8;
  int max_chunk_samples = 48000;  // sample frames per chunk
};

// Sampling as the protocol states it (dance.v1.Sampling): top_p and guidance 0 mean the model's default,
// an absent period_lock or music_guidance the model's default in a header and "keep" in a control.
struct SamplingRequest {
  float temperature = 1.0f;  // [0, 100]; 0 = greedy
  int top_k = 0;             // >= 0; 0 = off
  float top_p = 0.0f;        // [0, 1]; 0 = the model's default
  float guidance = 0.0f;     // [0, 100]; 0 = the model's default, 1 = off
  std::optional<float> period_lock;     // [0, 100] or -1 (the model's default); 0 = off
  std::optional<float> music_guidance;  // [0, 100] or -1 (the model's default); 1 = off
};

// The stream a client opens (StreamHeader, or the browser's start message), not yet validated.
struct StreamRequest {
  int sample_rate_hz = 0;
  int channels = 0;
  std::optional<PcmFormat> format;  // nullopt: the client named none the server knows
  StyleMix style;                   // empty = "none"
  uint64_t seed = 0;
  std::optional<SamplingRequest> sampling;  // nullopt: temperature 1, the model's defaults
  std::string client_name;
  bool omit_rotations = false;
  bool raw_feet = false;
  ControlSpec controls;  // empty = none
};

// A mid-stream change (Control, or the browser's control message), not yet validated.
struct ControlRequest {
  StyleMix style;                           // empty = keep the style
  std::optional<SamplingRequest> sampling;  // nullopt = keep the sampling options
  std::optional<ControlSpec> controls;      // set = replace the motion controls and path (empty = none)
  std::optional<SteerTarget> steer;         // set = replace the path with this target
};

// One live pose as a client sends it (PoseInput, or the browser's poses message), not yet validated.
enum class BodyPart { kUnspecified, kUpper, kLower, kAll };
struct PoseRequest {
  double time_ms = 0.0;
  std::vector<float> positions;  // kNumJoints x 3
  BodyPart part = BodyPart::kUnspecified;
};

struct ValidatedStream {
  StreamConfig config;
  PcmFormat format = PcmFormat::kF32Le;
  std::string client_name;
  bool omit_rotations = false;
};

struct ValidatedControl {
  std::optional<StyleMix> style;
  std::optional<SamplingConfig> sampling;
  std::optional<ControlSpec> controls;
  std::optional<SteerTarget> steer;
};

absl::StatusOr<ValidatedStream> ValidateStream(const StreamRequest& request, const ModelDescription& model,
                                               const StreamLimits& limits);
// Style and sampling; the controls and steering pass through unchecked (the session checks them when it
// applies them, and refuses bad ones with a warning rather than ending the stream).
absl::StatusOr<ValidatedControl> ValidateControl(const ControlRequest& request, const ModelDescription& model);
// Every name one of the model's styles (or "none"), every weight finite and >= 0, at most 64 entries.
absl::StatusOr<StyleMix> ValidateStyle(const StyleMix& style, const ModelDescription& model);
// The ranges above; maps the protocol's "0 = the model's default" onto the engine's negative values.
absl::StatusOr<SamplingConfig> ValidateSampling(const SamplingRequest& sampling);
// The shape of the controls (pose arrays of whole 24-joint frames, finite times and coordinates, sizes
// within kMaxControlFrames); the engine checks the rest when it builds them (errors prefixed "controls.").
absl::Status ValidateControlSpec(const ControlSpec& controls);
// A steering target: finite, a velocity of at most 10 m/s held for (0, 60] s, a time within the stream.
absl::Status ValidateSteer(const SteerTarget& steer);
// A pose: 24 x 3 finite coordinates within 100 m, a body part, a time in [0, 1e9] ms.
absl::StatusOr<LivePose> ValidatePose(const PoseRequest& pose);
// A chunk of `pcm_bytes` must be whole sample frames and at most limits.max_chunk_samples of them.
absl::Status ValidateChunk(size_t pcm_bytes, const ValidatedStream& stream, const StreamLimits& limits);

}  // namespace dance::server

#endif  // DANCE_SERVER_CORE_STREAM_REQUEST_H_
