// Turns decoded pose features into the skeleton's global joint positions and local joint rotations
// (docs/model.md section 7, docs/data.md, docs/rotations.md; Python reference
// training/data/representation.py):
//   1. root integration: theta_n = theta_{n-1} + yaw_rate_n, root_xz_n = root_xz_{n-1} + R(theta_n) (vx, vz),
//      the pelvis height taken absolute from the lower features (never integrated);
//   2. local -> global: J = R(theta) (local) + (root_x, 0, root_z);
//   3. bone-length projection onto the canonical skeleton (walking down from the pelvis);
//   4. per-joint rotations exactly as docs/rotations.md: body frames for pelvis and spine3, the shortest
//      arc for single-child joints, the parent's rotation for leaves; local = conj(G_parent) G, w >= 0.
//
// Usage:
//   PoseReconstructor rec(skeleton);
//   PoseState state;                                  // origin, facing +Z
//   rec.Reconstruct(upper45, lower31, state, &positions, &rotations);
//
// Thread safety: the reconstructor is immutable; PoseState belongs to one stream.
#ifndef DANCE_ENGINE_VQ_POSE_RECONSTRUCTOR_H_
#define DANCE_ENGINE_VQ_POSE_RECONSTRUCTOR_H_

#include <array>
#include <cstdint>

#include "Eigen/Core"
#include "Eigen/Geometry"
#include "engine/vq/skeleton.h"

namespace dance::engine {

inline constexpr int kUpperDims = 45;
inline constexpr int kLowerDims = 31;
inline constexpr int kLowerHeightIndex = 30;  // the pelvis height channel of the lower features (metres)

// The integrated root of one stream; copyable (snapshot = copy).
struct PoseState {
  double yaw = 0.0;     // theta, radians about +Y; 0 faces +Z
  double root_x = 0.0;  // metres
  double root_z = 0.0;
  int64_t frames = 0;   // frames reconstructed so far
};

class PoseReconstructor {
 public:
  // `skeleton` must outlive the reconstructor (the Model owns it).
  explicit PoseReconstructor(const Skeleton& skeleton) : skeleton_(skeleton) {}

  // upper: (45) 15 upper joints relative to the pelvis in the facing frame; lower: (31) 9 lower joints
  // relative to the pelvis (pelvis row = (0, height, 0)) then (vx, vz, yaw_rate, height).
  // `rotations` may be null (positions only).
  void Reconstruct(const float* upper, const float* lower, PoseState& state,
                   std::array<Eigen::Vector3f, kNumJoints>* positions,
                   std::array<Eigen::Quaternionf, kNumJoints>* rotations) const;

  // Step 3 alone, in place.
  void ProjectBoneLengths(std::array<Eigen::Vector3f, kNumJoints>& positions) const;
  // Step 4 alone: local rotations (docs/rotations.md); forward kinematics of the rest offsets with them
  // reproduces every single-child bone's direction of `positions`.
  void JointRotations(const std::array<Eigen::Vector3f, kNumJoints>& positions,
                      std::array<Eigen::Quaternionf, kNumJoints>* rotations) const;

 private:
  const Skeleton& skeleton_;
};

}  // namespace dance::engine

#endif  // DANCE_ENGINE_VQ_POSE_RECONSTRUCTOR_H_
