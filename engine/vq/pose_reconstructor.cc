#include "engine/vq/pose_reconstructor.h"

#include <cmath>

namespace dance::engine {
namespace {

// Rotation about +Y by `yaw` applied to (x, z): yaw 0 faces +Z, positive yaw turns +Z towards +X.
Eigen::Vector3f RotateY(const Eigen::Vector3f& v, double yaw) {
  const float c = static_cast<float>(std::cos(yaw)), s = static_cast<float>(std::sin(yaw));
  return Eigen::Vector3f(c * v.x() + s * v.z(), v.y(), -s * v.x() + c * v.z());
}

Eigen::Vector3f SafeNormalized(const Eigen::Vector3f& v, const Eigen::Vector3f& fallback) {
  const float n = v.norm();
  return n > 1e-8f ? Eigen::Vector3f(v / n) : fallback;
}

constexpr int kPelvis = 0, kLeftHip = 1, kRightHip = 2, kSpine1 = 3, kSpine3 = 9, kNeck = 12;
constexpr int kLeftCollar = 13, kRightCollar = 14;

// docs/rotations.md "frame(l, r, lo, hi)": columns x = normalize(l - r), y = normalize(h - (h.x) x) with
// h = hi - lo, z = x cross y.
Eigen::Matrix3f BodyFrame(const Eigen::Vector3f& l, const Eigen::Vector3f& r, const Eigen::Vector3f& lo,
                          const Eigen::Vector3f& hi) {
  const Eigen::Vector3f x = SafeNormalized(l - r, Eigen::Vector3f::UnitX());
  const Eigen::Vector3f h = hi - lo;
  const Eigen::Vector3f y = SafeNormalized(h - h.dot(x) * x, Eigen::Vector3f::UnitY());
  Eigen::Matrix3f f;
  f.col(0) = x;
  f.col(1) = y;
  f.col(2) = x.cross(y);
  return f;
}

// docs/rotations.md "arc(a, b)": normalize(1 + a.b, a x b) on unit vectors; opposite vectors turn half way
// about a x X (or a x Y when a is along X).
Eigen::Quaternionf ShortestArc(const Eigen::Vector3f& a_raw, const Eigen::Vector3f& b_raw) {
  const Eigen::Vector3f a = SafeNormalized(a_raw, Eigen::Vector3f::UnitY());
  const Eigen::Vector3f b = SafeNormalized(b_raw, a);
  const float dot = a.dot(b);
  if (dot < -1.0f + 1e-6f) {
    Eigen::Vector3f axis = a.cross(Eigen::Vector3f::UnitX());
    if (axis.norm() < 1e-6f) axis = a.cross(Eigen::Vector3f::UnitY());
    axis.normalize();
    return Eigen::Quaternionf(0.0f, axis.x(), axis.y(), axis.z());
  }
  const Eigen::Vector3f c = a.cross(b);
  return Eigen::Quaternionf(1.0f + dot, c.x(), c.y(), c.z()).normalized();
}

}  // namespace

void PoseReconstructor::Reconstruct(const float* upper, const float* lower, PoseState& state,
                                    std::array<Eigen::Vector3f, kNumJoints>* positions,
                                    std::array<Eigen::Quaternionf, kNumJoints>* rotations) const {
  const float vx = lower[27], vz = lower[28], yaw_rate = lower[29], height = lower[kLowerHeightIndex];
  state.yaw += yaw_rate;
  const Eigen::Vector3f step = RotateY(Eigen::Vector3f(vx, 0.0f, vz), state.yaw);
  state.root_x += step.x();
  state.root_z += step.z();
  ++state.frames;
  const Eigen::Vector3f root(static_cast<float>(state.root_x), 0.0f, static_cast<float>(state.root_z));
  const Eigen::Vector3f lift(0.0f, height, 0.0f);
  std::array<Eigen::Vector3f, kNumJoints>& p = *positions;
  for (size_t i = 0; i < kUpperJoints.size(); ++i) {
    const Eigen::Vector3f local = Eigen::Vector3f(upper[3 * i], upper[3 * i + 1], upper[3 * i + 2]) + lift;
    p[kUpperJoints[i]] = RotateY(local, state.yaw) + root;
  }
  for (size_t i = 0; i < kLowerJoints.size(); ++i) {
    const Eigen::Vector3f rel(lower[3 * i], lower[3 * i + 1], lower[3 * i + 2]);
    // The pelvis row carries (0, height, 0) itself; the others are relative to the pelvis.
    const Eigen::Vector3f local = kLowerJoints[i] == 0 ? lift : Eigen::Vector3f(rel + lift);
    p[kLowerJoints[i]] = RotateY(local, state.yaw) + root;
  }
  ProjectBoneLengths(p);
  if (rotations != nullptr) JointRotations(p, rotations);
}

void PoseReconstructor::ProjectBoneLengths(std::array<Eigen::Vector3f, kNumJoints>& positions) const {
  const std::array<Eigen::Vector3f, kNumJoints> raw = positions;
  for (int j = 1; j < kNumJoints; ++j) {
    const int parent = skeleton_.parents[j];
    const Eigen::Vector3f rest_dir = skeleton_.offsets[j] / skeleton_.bone_lengths[j];
    positions[j] = positions[parent] +
                   skeleton_.bone_lengths[j] * SafeNormalized(raw[j] - raw[parent], rest_dir);
  }
}

void PoseReconstructor::JointRotations(const std::array<Eigen::Vector3f, kNumJoints>& positions,
                                       std::array<Eigen::Quaternionf, kNumJoints>* rotations) const {
  // docs/rotations.md, step by step (training/data/rotations.py is the float64 reference).
  std::array<Eigen::Vector3f, kNumJoints> rest;
  rest[0].setZero();
  for (int j = 1; j < kNumJoints; ++j) rest[j] = rest[skeleton_.parents[j]] + skeleton_.offsets[j];
  std::array<Eigen::Quaternionf, kNumJoints> global;
  for (int j = 0; j < kNumJoints; ++j) {
    const int parent = skeleton_.parents[j];
    const Eigen::Quaternionf parent_rot = parent < 0 ? Eigen::Quaternionf::Identity() : global[parent];
    const std::vector<int>& kids = skeleton_.children[j];
    if (j == kPelvis || j == kSpine3) {
      const int l = j == kPelvis ? kLeftHip : kLeftCollar, r = j == kPelvis ? kRightHip : kRightCollar;
      const int hi = j == kPelvis ? kSpine1 : kNeck;
      const Eigen::Matrix3f posed = BodyFrame(positions[l], positions[r], positions[j], positions[hi]);
      const Eigen::Matrix3f rest_frame = BodyFrame(rest[l], rest[r], rest[j], rest[hi]);
      global[j] = Eigen::Quaternionf(Eigen::Matrix3f(posed * rest_frame.transpose())).normalized();
    } else if (kids.size() == 1) {
      const int c = kids[0];
      const Eigen::Vector3f a = parent_rot * skeleton_.offsets[c];
      const Eigen::Vector3f b = positions[c] - positions[j];
      global[j] = (ShortestArc(a, b) * parent_rot).normalized();
    } else {
      global[j] = parent_rot;  // leaves (and any other multi-child joint): keep the parent's rotation
    }
    Eigen::Quaternionf local = parent < 0 ? global[j] : (parent_rot.conjugate() * global[j]).normalized();
    if (local.w() < 0.0f) local.coeffs() = -local.coeffs();
    (*rotations)[j] = local;
  }
}

}  // namespace dance::engine
