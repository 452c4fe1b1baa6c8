// Controls: what a user tells the dancer to do, on top of the music (SGMD's controls, docs/controls.md).
// Every motion control is one thing to the engine, a MotionTrack: given joint positions on the audio
// timeline with, per frame, which joints are known. Seed motion knows every joint of its first frames;
// a given upper or lower half knows that half's joints on every frame; keyframes know every joint on a
// few frames; inpainting knows what its mask says. The session
//   - forces the codes of a stream (upper or lower body) on steps whose frames know that stream's joints
//     (the codes come from the VQ-VAE encoder on the given motion), so the model's state (KV caches, Mamba
//     states, decoder histories) follows the given motion;
//   - pulls the codes toward the next known pose within a horizon before it;
//   - composites every emitted frame: known joints exactly as given (in the given body's frame when the
//     pelvis is known, else relative to the generated pelvis and facing), the rest generated; the
//     generated dance is rigidly re-aligned at each known root so it continues from it, and crossfaded
//     into and out of known frames.
// A Trajectory steers the root along a floor path: codes ranked by the root motion they decode to, plus a
// bounded root correction.
//
// Usage:
//   Controls c;
//   c.motion = SeedTrack(clip, /*first_frame=*/0);             // or GivenHalfTrack, KeyframeTrack, ...
//   c.motion = CombineTracks(c.motion, KeyframeTrack(keys, key_frames));
//   c.trajectory = {{.t_s = 0, .x = 0, .z = 0}, {.t_s = 8, .x = 2, .z = 0}};
//   options.controls = c;                                      // SessionOptions; validated by Create
//
// Thread safety: plain values.
#ifndef DANCE_ENGINE_RUNTIME_CONTROLS_H_
#define DANCE_ENGINE_RUNTIME_CONTROLS_H_

#include <array>
#include <cstdint>
#include <optional>
#include <vector>

#include "Eigen/Core"
#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "engine/vq/pose_encoder.h"
#include "engine/vq/skeleton.h"

namespace dance::engine {

// The longest a MotionTrack may span: 3 hours at 30 fps (93 MB of positions).
inline constexpr int64_t kMaxTrackFrames = int64_t{30} * 3600 * 3;

// Bit j of a joint mask is joint j (SMPL order).
using JointMask = uint32_t;
inline constexpr JointMask kAllJoints = (JointMask{1} << kNumJoints) - 1;
JointMask UpperMask();  // the upper-body stream's 15 joints
JointMask LowerMask();  // the lower-body stream's 9 joints (with the pelvis: the root)

// Given motion over real 30 fps frames [first_frame, first_frame + positions.size()) of the audio
// timeline (frame m plays at m / 30 s); known[i] says which joints of positions[i] are given (0 = none).
struct MotionTrack {
  int64_t first_frame = 0;
  std::vector<JointPositions> positions;  // metres, Y up, SMPL order
  std::vector<JointMask> known;           // same length as positions
  bool empty() const { return positions.empty(); }
  int64_t end_frame() const { return first_frame + static_cast<int64_t>(positions.size()); }
  // The known joints of audio frame m (0 outside the track).
  JointMask KnownAt(int64_t m) const {
    return m >= first_frame && m < end_frame() ? known[m - first_frame] : 0;
  }
};

// A seed clip: every joint of every frame known.
MotionTrack SeedTrack(std::vector<JointPositions> clip, int64_t first_frame);
// One half of a dance given on every frame (upper = true: the 15 upper joints; false: the 9 lower ones).
MotionTrack GivenHalfTrack(std::vector<JointPositions> motion, int64_t first_frame, bool upper);
// Key poses at audio frames `frames` (one per pose): every joint known on those frames only.
// InvalidArgument unless the frames are >= 0, ascending, at least one step (4 frames) apart and within
// kMaxTrackFrames of each other.
absl::StatusOr<MotionTrack> KeyframeTrack(const std::vector<JointPositions>& poses,
                                          const std::vector<int64_t>& frames);
// A recorded dance with a mask: known[i] per frame (e.g. from a dance-mask/v1 file).
MotionTrack MaskedTrack(std::vector<JointPositions> dance, int64_t first_frame, std::vector<JointMask> known);
// The union of two tracks: where both know a joint, `b` wins. The result spans both (the caller keeps
// that within kMaxTrackFrames; ValidateControls refuses more).
MotionTrack CombineTracks(const MotionTrack& a, const MotionTrack& b);

struct TrajectoryPoint {
  double t_s = 0.0;              // audio time, seconds
  float x = 0.0f, z = 0.0f;      // metres on the floor
  std::optional<float> facing;   // radians about +Y, 0 faces +Z
};

struct ControlWeights {
  float key_pull = 4.0f;          // logit bias toward the next known pose's code within key_horizon_s
  float key_horizon_s = 1.0f;     // seconds before a known frame in which codes are pulled toward it
  float blend_in_s = 0.5f;        // crossfade from the generated dance into a known frame
  float blend_out_s = 0.5f;       // crossfade from a known frame back into the generated dance
  float trajectory_weight = 1.0f; // strength of the trajectory's code ranking
  float trajectory_lead_s = 0.5f; // the path point the codes aim at, ahead of the emitted period
  float root_correction_mps = 2.0f;  // the largest root correction toward the path, metres per second
};

struct Controls {
  MotionTrack motion;
  std::vector<TrajectoryPoint> trajectory;  // empty = none; times strictly increasing
  ControlWeights weights;
  bool empty() const { return motion.empty() && trajectory.empty(); }
};

// InvalidArgument naming what is wrong: mismatched lengths, NaN or absurd positions (> 100 m), a mask
// with bits outside the 24 joints, a negative first frame, trajectory times not strictly increasing or
// negative, non-finite coordinates, bad weights.
absl::Status ValidateControls(const Controls& controls);

}  // namespace dance::engine

#endif  // DANCE_ENGINE_RUNTIME_CONTROLS_H_
