// SGMD's motion vector and a window's canonical frame (docs/diffusion.md section 2; reference
// training/diffusion/motion.py).
//
// Usage:
//   CanonicalFrame f = FrameOf(world[0]);                // the first frame's pelvis and facing
//   std::vector<JointPositions> local = ToFrame(world, f);
//   Eigen::MatrixXf v = MotionVectors(local);            // (78, T), contacts from the positions
//   JointPositions p = PositionsOfVector(v.col(n));      // the inverse (contacts ignored)
//
// Thread safety: pure functions.
#ifndef DANCE_ENGINE_DIFFUSION_MOTION_VECTOR_H_
#define DANCE_ENGINE_DIFFUSION_MOTION_VECTOR_H_

#include <vector>

#include "Eigen/Core"
#include "engine/vq/pose_encoder.h"

namespace dance::engine {

inline constexpr int kMotionDims = 78;
inline constexpr int kMotionRoot = 0;      // pelvis x, y, z
inline constexpr int kMotionHeading = 3;   // sin, cos of the facing yaw
inline constexpr int kMotionLocal = 5;     // joints 1..23, 3 each, relative to the pelvis in the facing frame
inline constexpr int kMotionContact = 74;  // joints 7, 8, 10, 11
inline constexpr float kContactSpeed = 0.3f;  // m/s

// A window's frame: world -> window is p' = R_y(-yaw) (p - (x, 0, z)).
struct CanonicalFrame {
  double yaw = 0.0;
  double x = 0.0, z = 0.0;
};

CanonicalFrame FrameOf(const JointPositions& first_frame);
JointPositions ToFrame(const JointPositions& world, const CanonicalFrame& frame);
JointPositions FromFrame(const JointPositions& local, const CanonicalFrame& frame);
std::vector<JointPositions> ToFrame(const std::vector<JointPositions>& world, const CanonicalFrame& frame);

// (78, T); contacts from the speeds between frames (the last frame repeats the one before).
Eigen::MatrixXf MotionVectors(const std::vector<JointPositions>& positions);
// One frame's vector without contacts (dims 74-77 left 0): pelvis, heading and local joints.
Eigen::VectorXf PoseVector(const JointPositions& positions);
// The inverse: pelvis + R_y(atan2(v3, v4)) local.
JointPositions PositionsOfVector(const Eigen::Ref<const Eigen::VectorXf>& v);

}  // namespace dance::engine

#endif  // DANCE_ENGINE_DIFFUSION_MOTION_VECTOR_H_
