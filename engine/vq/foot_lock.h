// Foot lock: a causal, per-frame clean-up of the decoded poses that holds a planted foot still on the
// floor by bending its leg (two-bone inverse kinematics, hip fixed), instead of letting it drift with the
// decoded motion (docs/model.md section 7, "Foot lock").
//
// For each foot, every frame:
//   1. the raw foot point r (mean of the ankle and the foot joint, horizontal) moved by d since the last
//      frame; its speed s = |d| x 30 fps is smoothed, s' <- s' + kFootLockSpeedSmoothing (s - s');
//   2. contact weight w = ramp(foot joint height; kFootLockHeightFull..kFootLockHeightNone)
//                       x ramp(s'; kFootLockSpeedFull..kFootLockSpeedNone)     (1 planted .. 0 free)
//                       x ramp(hip to held ankle / (thigh + shin); kFootLockExtension*), only when the
//                         hold lengthens the leg (a straightening leg lets go; a straight leg whose
//                         foot stays behind is held);
//   3. the foot's horizontal correction c cancels the planted share of the motion, c <- c - w d, and
//      returns to zero while the foot is free, c <- c (1 - kFootLockRelease (1 - w)); |c| <=
//      kFootLockMaxShift, and c shrinks until the leg can reach (hip to ankle <= 0.999 of thigh + shin,
//      or the decoded leg's own length if longer);
//   4. the ankle and the foot joint move by c; the knee is placed on the circle the thigh and shin allow,
//      toward the decoded knee's bend (never backwards; forward for a straight leg). Bone lengths stay
//      exact; the hips, the pelvis and the upper body are untouched, so the root path and the music timing
//      do not change.
// A foot that is high or moving fast is never held, and its correction fades within a few frames of swing,
// where the foot's own motion hides it. Measured on the default model's dances (docs/research-log.md "Foot
// lock"): foot skating and PFC fall toward the real dancers', jitter and FID change within noise.
//
// Usage:
//   FootLock lock(skeleton);
//   FootLockState state;                 // one per stream; copyable (snapshot = copy)
//   lock.Apply(state, &positions);       // positions: bone lengths canonical (after ProjectBoneLengths)
//
// Thread safety: FootLock is immutable; a FootLockState belongs to one stream.
#ifndef DANCE_ENGINE_VQ_FOOT_LOCK_H_
#define DANCE_ENGINE_VQ_FOOT_LOCK_H_

#include <array>

#include "Eigen/Core"
#include "engine/vq/skeleton.h"

namespace dance::engine {

// Contact thresholds, chosen on the default model's validation dances (docs/research-log.md "Foot lock"): the
// real dancers' foot joint sits below 3 cm in about a quarter of their frames; the lower foot's median
// horizontal speed is 0.3-0.4 m/s (ballroom feet slide), so only slower feet are held fully.
inline constexpr float kFootLockHeightFull = 0.03f;   // metres: foot joint at or below: height weight 1
inline constexpr float kFootLockHeightNone = 0.10f;   // at or above: 0
inline constexpr float kFootLockSpeedFull = 0.15f;    // m/s, smoothed: at or below: speed weight 1
inline constexpr float kFootLockSpeedNone = 1.0f;     // at or above: 0
inline constexpr float kFootLockSpeedSmoothing = 0.5f;
inline constexpr float kFootLockRelease = 0.15f;      // share of the correction dropped per free frame
inline constexpr float kFootLockMaxShift = 0.15f;     // metres
// Hip-to-held-ankle distance as a share of thigh + shin: at or below: extension weight 1; at or above: 0.
inline constexpr float kFootLockExtensionFull = 0.99f;
inline constexpr float kFootLockExtensionNone = 0.998f;

struct FootLockState {
  struct Foot {
    Eigen::Vector2f correction = Eigen::Vector2f::Zero();  // (x, z) metres added to the ankle and foot
    Eigen::Vector2f previous = Eigen::Vector2f::Zero();    // the raw foot point of the last frame
    float speed = 0.0f;                                    // smoothed raw speed, m/s
    bool has_previous = false;
  };
  std::array<Foot, 2> feet;  // left, right
};

class FootLock {
 public:
  // Copies the leg bone lengths of `skeleton`.
  explicit FootLock(const Skeleton& skeleton);

  // One frame, in place: ankles, feet and knees of `positions` (30 fps frames, in order).
  void Apply(FootLockState& state, std::array<Eigen::Vector3f, kNumJoints>* positions) const;

  // The contact weight of step 2 (exposed for tests).
  static float ContactWeight(float foot_height, float smoothed_speed);

 private:
  struct Leg {
    int hip, knee, ankle, foot;
    float thigh, shin;  // canonical bone lengths
  };
  std::array<Leg, 2> legs_;
};

}  // namespace dance::engine

#endif  // DANCE_ENGINE_VQ_FOOT_LOCK_H_
