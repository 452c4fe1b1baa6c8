#include "engine/diffusion/motion_vector.h"

#include <cmath>

#include "absl/base/internal/raw_logging.h"

namespace dance::engine {
namespace {

constexpr int kContactJoints[4] = {7, 8, 10, 11};  // left ankle, right ankle, left foot, right foot
constexpr double kFps = 30.0;

// R_y(yaw) p = (c x + s z, y, -s x + c z) (docs/model.md); R_y(-yaw) flips the sign of s. In double like the
// reference (training/data/representation.py rot_y on float64).
Eigen::Vector3d RotateY(double c, double s, const Eigen::Vector3d& p) {
  return Eigen::Vector3d(c * p.x() + s * p.z(), p.y(), -s * p.x() + c * p.z());
}

}  // namespace

CanonicalFrame FrameOf(const JointPositions& first_frame) {
  CanonicalFrame f;
  f.yaw = FacingYaw(first_frame);
  f.x = first_frame[0].x();
  f.z = first_frame[0].z();
  return f;
}

JointPositions ToFrame(const JointPositions& world, const CanonicalFrame& frame) {
  const double c = std::cos(frame.yaw), s = std::sin(frame.yaw);
  const Eigen::Vector3d origin(frame.x, 0.0, frame.z);
  JointPositions out;
  for (int j = 0; j < kNumJoints; ++j) out[j] = RotateY(c, -s, world[j].cast<double>() - origin).cast<float>();
  return out;
}

JointPositions FromFrame(const JointPositions& local, const CanonicalFrame& frame) {
  const double c = std::cos(frame.yaw), s = std::sin(frame.yaw);
  const Eigen::Vector3d origin(frame.x, 0.0, frame.z);
  JointPositions out;
  for (int j = 0; j < kNumJoints; ++j) out[j] = (RotateY(c, s, local[j].cast<double>()) + origin).cast<float>();
  return out;
}

std::vector<JointPositions> ToFrame(const std::vector<JointPositions>& world, const CanonicalFrame& frame) {
  std::vector<JointPositions> out;
  out.reserve(world.size());
  for (const JointPositions& p : world) out.push_back(ToFrame(p, frame));
  return out;
}

Eigen::MatrixXf MotionVectors(const std::vector<JointPositions>& positions) {
  const int t = static_cast<int>(positions.size());
  Eigen::MatrixXf v(kMotionDims, t);
  for (int n = 0; n < t; ++n) v.col(n) = PoseVector(positions[n]);
  // A contact compares the frame with the next one; the last frame repeats the one before (a lone frame
  // has none).
  for (int n = 0; n + 1 < t; ++n) {
    for (int i = 0; i < 4; ++i) {
      const int j = kContactJoints[i];
      const double speed = (positions[n + 1][j].cast<double>() - positions[n][j].cast<double>()).norm() * kFps;
      v(kMotionContact + i, n) = speed < kContactSpeed ? 1.0f : 0.0f;
    }
  }
  if (t > 1) v.col(t - 1).tail<4>() = v.col(t - 2).tail<4>();
  return v;
}

Eigen::VectorXf PoseVector(const JointPositions& positions) {
  Eigen::VectorXf v = Eigen::VectorXf::Zero(kMotionDims);
  const double theta = FacingYaw(positions);
  const double c = std::cos(theta), s = std::sin(theta);
  const Eigen::Vector3d pelvis = positions[0].cast<double>();
  v.segment<3>(kMotionRoot) = positions[0];
  v(kMotionHeading) = static_cast<float>(s);
  v(kMotionHeading + 1) = static_cast<float>(c);
  for (int j = 1; j < kNumJoints; ++j) {
    v.segment<3>(kMotionLocal + 3 * (j - 1)) = RotateY(c, -s, positions[j].cast<double>() - pelvis).cast<float>();
  }
  return v;
}

JointPositions PositionsOfVector(const Eigen::Ref<const Eigen::VectorXf>& v) {
  ABSL_RAW_CHECK(v.size() >= kMotionContact, "PositionsOfVector: a motion vector has 78 values");
  // The heading pair need not be unit (a model's output): atan2 reads only its direction.
  const double theta = std::atan2(static_cast<double>(v(kMotionHeading)), static_cast<double>(v(kMotionHeading + 1)));
  const double c = std::cos(theta), s = std::sin(theta);
  const Eigen::Vector3d pelvis = v.segment<3>(kMotionRoot).cast<double>();
  JointPositions out;
  out[0] = v.segment<3>(kMotionRoot);
  for (int j = 1; j < kNumJoints; ++j) {
    const Eigen::Vector3d local = v.segment<3>(kMotionLocal + 3 * (j - 1)).cast<double>();
    out[j] = (pelvis + RotateY(c, s, local)).cast<float>();
  }
  return out;
}

}  // namespace dance::engine
