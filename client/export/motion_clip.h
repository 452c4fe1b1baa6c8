// MotionClip: a dance as plain arrays (no proto, no engine types), the input of the avatar formats
// (glTF 2.0 with a skinned skeleton, VRM Animation, VMC). Both dance-generate (engine frames) and
// dance-client (proto frames) fill one.
//
// Conventions (docs/rotations.md): metres, Y up, the rest pose faces +Z with the body's left at +X, every
// local rotation is the identity in the rest pose, quaternions (w, x, y, z), G_j = G_parent(j) L_j.
//
// Usage:
//   MotionClip clip = ...;                       // joint_names, parents, rest_offsets, fps, frames
//   if (absl::Status s = ValidateClip(clip); !s.ok()) return s;
//   std::array<float, 3> p = GlobalPositions(clip, t)[j];
//
// Thread safety: plain data; the functions are pure.
#ifndef DANCE_CLIENT_EXPORT_MOTION_CLIP_H_
#define DANCE_CLIENT_EXPORT_MOTION_CLIP_H_

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/status.h"

namespace dance::client {

using Vec3 = std::array<float, 3>;
using Quat = std::array<float, 4>;  // (w, x, y, z)

struct MotionClip {
  double fps = 30.0;
  std::vector<std::string> joint_names;  // J
  std::vector<int> parents;              // J; parents[0] = -1, parents[j] < j
  std::vector<Vec3> rest_offsets;        // J, offset from the parent in the rest pose, metres
  std::vector<Vec3> root_positions;      // T, the root joint's (pelvis's) world position
  std::vector<Quat> rotations;           // T * J, local rotations, frame-major: rotations[t * J + j]

  int64_t num_frames() const { return static_cast<int64_t>(root_positions.size()); }
  int num_joints() const { return static_cast<int>(parents.size()); }
  const Quat& rotation(int64_t t, int j) const { return rotations[t * num_joints() + j]; }
};

// InvalidArgument unless the arrays agree in size, the parents are a tree in order (parents[0] = -1,
// parents[j] < j), fps > 0 and every value is finite.
absl::Status ValidateClip(const MotionClip& clip);

// Hamilton product a * b and the rotation of v by q, in float.
Quat QuatMul(const Quat& a, const Quat& b);
Vec3 QuatRotate(const Quat& q, const Vec3& v);
Quat QuatConj(const Quat& q);
// Spherical interpolation between unit quaternions along the shorter arc, u in [0, 1].
Quat QuatSlerp(const Quat& a, const Quat& b, float u);

// Forward kinematics of frame t: global positions of the J joints (root at root_positions[t]).
std::vector<Vec3> GlobalPositions(const MotionClip& clip, int64_t t);
// Rest-pose global positions (root at the origin).
std::vector<Vec3> RestPositions(const MotionClip& clip);

}  // namespace dance::client

#endif  // DANCE_CLIENT_EXPORT_MOTION_CLIP_H_
