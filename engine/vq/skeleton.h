// The canonical 24-joint SMPL skeleton carried in the weights file's metadata "skeleton"
// ({"joint_names": [24], "parents": [24], "rest_offsets": [24][3], optional "bone_lengths": [24]}, metres, Y up, the rest pose faces +Z
// with the body's left on +X; see docs/data.md).
//
// Thread safety: a plain immutable value after Parse.
#ifndef DANCE_ENGINE_VQ_SKELETON_H_
#define DANCE_ENGINE_VQ_SKELETON_H_

#include <array>
#include <string>
#include <vector>

#include "Eigen/Core"
#include "absl/status/statusor.h"
#include "nlohmann/json.hpp"

namespace dance::engine {

inline constexpr int kNumJoints = 24;
// SMPL joint indices of the upper (15) and lower (9) body streams, in the order of their pose features.
inline constexpr std::array<int, 15> kUpperJoints = {3, 6, 9, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22, 23};
inline constexpr std::array<int, 9> kLowerJoints = {0, 1, 2, 4, 5, 7, 8, 10, 11};

struct Skeleton {
  std::vector<std::string> joint_names;                 // 24
  std::array<int, kNumJoints> parents{};                // parents[0] = -1; parents[j] < j
  std::array<Eigen::Vector3f, kNumJoints> offsets{};    // rest offset from the parent, metres
  std::array<float, kNumJoints> bone_lengths{};         // "bone_lengths" if the file has them, else |offsets[j]|
  std::array<std::vector<int>, kNumJoints> children{};

  // Parses metadata["skeleton"]; InvalidArgument when malformed.
  static absl::StatusOr<Skeleton> FromMetadata(const nlohmann::json& metadata);
  // The default SMPL names (used for BVH and JSON when the file carries none).
  static const std::array<const char*, kNumJoints>& DefaultJointNames();
};

}  // namespace dance::engine

#endif  // DANCE_ENGINE_VQ_SKELETON_H_
