// MotionControl: a session's controls (controls.h) at run time. Built once from the Controls (the given
// motion is encoded to codes per stream with the model's VQ encoders), then asked twice per step:
//   ForStep: which codes the step must take (a stream whose joints are known over the emitted period),
//            which code to pull toward (the next known pose within the key horizon), and the trajectory's
//            bias over the lower codes (their decoded root motion against the path ahead);
//   Composite: each emitted frame, before the foot lock: known joints as given, the rest generated and
//            rigidly aligned to the last known root, crossfades at the seams, the bounded root correction
//            toward the path.
// docs/controls.md has the design and its measurements.
//
// State: the alignment and the seam memory live in MotionControlState (snapshot = copy). Not thread-safe.
#ifndef DANCE_ENGINE_RUNTIME_INTERNAL_MOTION_CONTROL_H_
#define DANCE_ENGINE_RUNTIME_INTERNAL_MOTION_CONTROL_H_

#include <cstdint>
#include <memory>
#include <vector>

#include "Eigen/Core"
#include "absl/status/statusor.h"
#include "engine/runtime/controls.h"
#include "engine/runtime/internal/sampling_policy.h"
#include "engine/runtime/model.h"
#include "engine/runtime/pose_frame.h"
#include "engine/vq/pose_reconstructor.h"  // PoseState
#include "engine/vq/vq_decoder.h"

namespace dance::engine {

// The trajectory ranks this many of a step's most likely lower codes by the root motion they decode to.
inline constexpr int kTrajectoryCandidates = 32;

// The controls of a session with what was derived from them once (the given codes, the known frames);
// immutable, shared by the state and its snapshots.
struct ControlPlan {
  Controls controls;
  std::vector<int> codes[2];         // per track frame: the given code of each stream, or -1
  // Whether a frame's codes may be forced: a run of at least one code's frames knows the stream. A key
  // pose alone is only pulled toward (forcing its held code jerked the decoded motion 0.27 s on either
  // side of the key; docs/controls.md).
  std::vector<uint8_t> forceable[2];
  std::vector<int64_t> known_frames; // audio frames with any known joint, ascending
};

struct MotionControlState {
  std::shared_ptr<const ControlPlan> plan;  // null = no controls
  // The rigid map from the generated dance to the output: yaw about +Y by `yaw`, then + (x, 0, z).
  double yaw = 0.0, x = 0.0, z = 0.0;
  double correction_x = 0.0, correction_z = 0.0;  // the trajectory's last root correction, m per frame
  bool on_path = false;           // the dance has been moved onto the path's start
  int64_t last_known = -1;        // the last emitted frame with known joints (-1 = none yet)
  JointPositions last_pose{};     // that frame's output
};

class MotionControl {
 public:
  // InvalidArgument for invalid controls; FailedPrecondition if motion is given and the model has no
  // encoders.
  static absl::StatusOr<MotionControl> Create(const Model& model, const Controls& controls);

  bool active() const { return state_.plan != nullptr; }
  // Replaces the controls from the next step on (live: a new path or target, a hand-over clip, the latest
  // poses of a given half); the alignment and seam memory carry on, so the dance does not jump. Same
  // errors as Create.
  absl::Status SetControls(const Controls& controls);
  // The control of the step that emits real frames [first_real, last_real] (estimated for a
  // tempo-normalised model from its clock); `root` and `yaw` are the generated root now and `rate` the
  // warped frames per real frame (1 for fixed rate). The returned bias pointer is valid until the next call.
  // `lower_state` is the lower decoder's state now and `lower_logits` the step's conditional lower logits
  // (K): the trajectory ranks the kTrajectoryCandidates most likely codes by the root motion each decodes
  // to from that state.
  StepControl ForStep(double first_real, double last_real, const PoseState& root, double rate,
                      const VqDecoderState& lower_state, const float* lower_logits);
  // Composites emitted frame `frame` (positions as generated and bone-projected) in place; returns true if
  // its lower body was given (the foot lock must leave it alone).
  bool Composite(PoseFrame& frame);

  const MotionControlState& state() const { return state_; }
  // InvalidArgument if the state's plan has codes outside this model's codebooks.
  absl::Status Validate(const MotionControlState& state) const;
  void Restore(const MotionControlState& state) { state_ = state; }
  // Back to the start with `plan` (the session's creation controls).
  void Reset(std::shared_ptr<const ControlPlan> plan) {
    state_ = MotionControlState();
    state_.plan = std::move(plan);
  }
  // The plan the session was created with (Reset returns to it).
  const std::shared_ptr<const ControlPlan>& initial_plan() const { return initial_plan_; }

 private:
  explicit MotionControl(const Model& model);
  // Validates `controls` and derives their plan (null for empty controls).
  absl::StatusOr<std::shared_ptr<const ControlPlan>> MakePlan(const Controls& controls) const;
  const ControlPlan& plan() const { return *state_.plan; }
  // The code of `stream` given at audio frame m (-1 if that stream's joints are not all known there).
  int GivenCode(int stream, int64_t m) const;
  // The same where the code may be forced (ControlPlan::forceable), else -1.
  int ForcedCode(int stream, int64_t m) const;
  // The path point at audio time t (clamped to the path's ends); facing if the points give it.
  Eigen::Vector2d PathAt(double t_s) const;
  bool PathFacingAt(double t_s, double* facing) const;
  void BlendPoses(const JointPositions& a, const JointPositions& b, double t, JointMask mask,
                  JointPositions* out) const;
  // Applies the alignment to `p` (in place).
  void Align(JointPositions& p) const;
  // Turns the alignment by `dyaw` about `pivot` (output coordinates), then moves it by (dx, dz).
  void TurnAndMoveAlignment(double dyaw, const Eigen::Vector3f& pivot, double dx, double dz);
  // The same, and moves `p` (already aligned) with it.
  void TurnAndMove(double dyaw, const Eigen::Vector3f& pivot, double dx, double dz, JointPositions& p);

  const Model* model_;
  std::vector<float> lower_bias_;   // (K) scratch of the trajectory
  std::vector<int> candidates_;     // scratch of the trajectory: candidate lower codes
  std::vector<VqDecoderState> candidate_states_;
  std::vector<VqDecoderState*> candidate_ptrs_;
  VqDecoderScratch candidate_scratch_;
  MotionControlState state_;
  std::shared_ptr<const ControlPlan> initial_plan_;
};

}  // namespace dance::engine

#endif  // DANCE_ENGINE_RUNTIME_INTERNAL_MOTION_CONTROL_H_
