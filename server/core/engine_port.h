// The server's view of the engine: a narrow port over dance::engine::Session / StepBatch.
//
// The server never includes engine headers outside core/engine_backend.cc, which includes only the
// engine's public header (engine/engine.h). Everything the server needs from the engine is here: open a
// stream, push audio, ask how many steps are ready, advance many streams in one batched step, collect pose
// frames. The real implementation (LoadEngineBackend) wraps engine::Session; unit tests of the core may
// supply a labelled test double (tests/server/testing/fake_engine.h).
//
// Usage:
//   ASSIGN_OR_RETURN(std::unique_ptr<EngineBackend> backend, LoadEngineBackend("models/test-tiny.dncw"));
//   ASSIGN_OR_RETURN(std::unique_ptr<EngineStream> s, backend->Open(config));
//   s->PushAudio(samples); while (s->StepsReady() > 0) backend->StepBatch({s.get()}); s->PopFrames(&out);
//
// Thread safety: EngineBackend is immutable after creation and safe to share across threads (Open and
// StepBatch may run concurrently on disjoint streams). An EngineStream has one owner thread at a time.
#ifndef DANCE_SERVER_CORE_ENGINE_PORT_H_
#define DANCE_SERVER_CORE_ENGINE_PORT_H_

#include <array>
#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/types/span.h"

namespace dance::server {

inline constexpr int kNumJoints = 24;

struct SamplingConfig {
  float temperature = 1.0f;  // 0 = greedy
  int top_k = 0;             // 0 = off
  float top_p = -1.0f;       // 1 = off, negative = the model's default
  float guidance = -1.0f;    // 1 = off, negative = the model's default
  // 0 = off, negative = the model's default for the top style (follows style changes); unset = the model's
  // default in a StreamHeader, the setting in effect in a Control.
  std::optional<float> period_lock;
  // 1 = off, negative = the model's default; unset = the model's default in a StreamHeader, the setting in
  // effect in a Control.
  std::optional<float> music_guidance;
};

using StyleMix = std::vector<std::pair<std::string, float>>;  // (style name, weight >= 0)

// The controls as a client states them (dance.v1.MotionControls), times in seconds on the input timeline;
// the engine reads and checks them (engine/runtime/control_spec.h).
struct MotionSpec {
  std::vector<float> positions;  // frames x kNumJoints x 3, metres; or
  std::string file;              // a dance-motion/v1 JSON or BVH file's bytes
  double start_s = 0.0;
  std::vector<double> times_s;   // poses only: each pose's time (keyframes)
  bool empty() const { return positions.empty() && file.empty(); }
};
struct MaskSpanSpec {
  double start_s = 0.0, end_s = 0.0;
  std::vector<std::string> joints;  // "all", "upper", "lower" or SMPL names
};
struct PathPointSpec {
  double t_s = 0.0;
  float x = 0.0f, z = 0.0f;
  std::optional<float> facing;
};
struct ControlSpec {
  MotionSpec seed, given_upper, given_lower, keyframes, inpaint;
  std::vector<MaskSpanSpec> inpaint_known;
  std::vector<PathPointSpec> trajectory;
  bool empty() const {
    return seed.empty() && given_upper.empty() && given_lower.empty() && keyframes.empty() && inpaint.empty() &&
           inpaint_known.empty() && trajectory.empty();
  }
};

// Live steering (dance.v1.SteerTarget): be at a point at a time, or travel at a velocity for a while.
struct SteerTarget {
  enum class Kind { kPoint, kVelocity };
  Kind kind = Kind::kPoint;
  double t_s = 0.0;          // point: when (input timeline)
  float x = 0.0f, z = 0.0f;  // point: where (m); velocity: m/s
  std::optional<float> facing;
  double hold_s = 1.0;       // velocity: for how long
};

// Bit j = SMPL joint j.
using JointBits = uint32_t;
inline constexpr JointBits kUpperJointBits = 0xFFF248;  // spine1, spine2, spine3, neck, collars, head, arms
inline constexpr JointBits kLowerJointBits = 0x000DB7;  // pelvis, hips, knees, ankles, feet
inline constexpr JointBits kAllJointBits = 0xFFFFFF;

// One live pose of a given body part (dance.v1.PoseInput).
struct LivePose {
  int64_t frame = 0;  // input timeline, 30 fps frame (round(time x 30))
  std::array<float, kNumJoints * 3> positions{};
  JointBits joints = 0;
};

struct StreamConfig {
  int sample_rate_hz = 24000;  // input rate, Hz
  int channels = 1;            // interleaved input channels
  StyleMix style;              // empty = "none"
  uint64_t seed = 0;
  SamplingConfig sampling;
  bool foot_lock = true;       // false = legs and feet as decoded (StreamHeader.raw_feet)
  ControlSpec controls;        // empty = none
};

// What the loaded model tells clients (SessionInfo / ModelInfo).
struct ModelDescription {
  std::string model_id;
  double latency_ms = 0.0;        // declared algorithmic latency
  double fps = 30.0;
  int samples_per_step = 3200;    // at 24 kHz
  int frames_per_step = 4;
  std::vector<std::string> joint_names;  // kNumJoints
  std::vector<int> parents;              // kNumJoints, -1 = root
  std::vector<float> rest_offsets;       // kNumJoints * 3, metres
  std::vector<std::string> styles;
  float default_period_lock = 0.0f;  // Sampling.period_lock when absent (0 = off) and the style is "none"
  std::map<std::string, float> style_period_lock;  // per style: Sampling.period_lock when absent
  float default_guidance = 1.0f;     // Sampling.guidance when 0 (1 = off)
  float default_music_guidance = 1.0f;  // Sampling.music_guidance when absent (1 = off)
  float default_top_p = 1.0f;        // Sampling.top_p when 0 (1 = no cut)
  double pose_latency_ms = 0.0;      // how far live poses must reach past a frame before it is danced
};

struct FrameData {
  int64_t index = 0;                           // 30 fps frame index since stream start
  double time_s = 0.0;                         // input timeline, seconds
  std::array<float, kNumJoints * 3> positions; // metres, Y up
  std::array<float, kNumJoints * 4> rotations; // (w, x, y, z) per joint
  int upper_code = 0;
  int lower_code = 0;
};

// One performer's engine state. Not thread-safe: one owner thread at a time.
class EngineStream {
 public:
  virtual ~EngineStream() = default;
  virtual absl::Status PushAudio(absl::Span<const float> interleaved) = 0;
  virtual absl::Status PushAudioInt16(absl::Span<const int16_t> interleaved) = 0;
  virtual void EndOfAudio() = 0;
  // Steps whose audio has fully arrived and that have not been taken yet.
  virtual int StepsReady() const = 0;
  // Appends the frames produced so far (in order) to *out.
  virtual void PopFrames(std::vector<FrameData>* out) = 0;
  // Appends the beats found in the audio pushed so far and not popped yet (seconds on the input timeline,
  // ascending) to *out. Engines without a beat tracker give none.
  virtual void PopBeats(std::vector<double>* out) { (void)out; }
  virtual absl::Status SetStyle(const StyleMix& style) = 0;
  virtual absl::Status SetSampling(const SamplingConfig& sampling) = 0;

  // ---- controls (engines without them answer UNIMPLEMENTED) ----
  // Replaces the motion controls and the path from the next step on (empty = none); a seed that would
  // start before the next frame starts at it. INVALID_ARGUMENT naming what is wrong (nothing changes).
  virtual absl::Status SetControls(const ControlSpec& controls);
  // Replaces the path with one toward `target` from where the dancer is now; a zero velocity clears it.
  virtual absl::Status Steer(const SteerTarget& target);
  // Live poses, frames increasing (a pose for a frame already taken replaces it); kept for the last
  // seconds. INVALID_ARGUMENT for a pose out of order (the others are kept).
  virtual absl::Status PushPoses(absl::Span<const LivePose> poses);
  // No more live poses for now (the input stopped): stepping stops waiting for them.
  virtual void EndPoses() {}
  // Whether the next step must wait for live poses (they do not yet reach the frames it needs).
  virtual bool WaitsForPoses() const { return false; }
  // Applies what SetControls / Steer / PushPoses changed, before a step. An error leaves the controls in
  // effect unchanged.
  virtual absl::Status CommitControls() { return absl::OkStatus(); }
};

class EngineBackend {
 public:
  virtual ~EngineBackend() = default;
  virtual const ModelDescription& Describe() const = 0;
  // INVALID_ARGUMENT for a bad config (sample rate, channels, unknown style).
  virtual absl::StatusOr<std::unique_ptr<EngineStream>> Open(const StreamConfig& config) const = 0;
  // Advances each stream (all created by this backend, each with StepsReady() > 0) by one step, in one
  // pass over the weights.
  virtual absl::Status StepBatch(absl::Span<EngineStream* const> streams) const = 0;
};

// Loads a .dncw model with the real engine. Errors: whatever the engine's loader returns.
absl::StatusOr<std::unique_ptr<EngineBackend>> LoadEngineBackend(const std::string& model_path);

}  // namespace dance::server

#endif  // DANCE_SERVER_CORE_ENGINE_PORT_H_
