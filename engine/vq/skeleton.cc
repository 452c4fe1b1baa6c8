#include "engine/vq/skeleton.h"

#include "absl/status/status.h"
#include "absl/strings/str_cat.h"

namespace dance::engine {

const std::array<const char*, kNumJoints>& Skeleton::DefaultJointNames() {
  static const std::array<const char*, kNumJoints> kNames = {
      "pelvis",        "left_hip",       "right_hip",      "spine1",     "left_knee",   "right_knee",
      "spine2",        "left_ankle",     "right_ankle",    "spine3",     "left_foot",   "right_foot",
      "neck",          "left_collar",    "right_collar",   "head",       "left_shoulder", "right_shoulder",
      "left_elbow",    "right_elbow",    "left_wrist",     "right_wrist", "left_hand",  "right_hand"};
  return kNames;
}

absl::StatusOr<Skeleton> Skeleton::FromMetadata(const nlohmann::json& metadata) {
  if (!metadata.contains("skeleton") || !metadata["skeleton"].is_object()) {
    return absl::InvalidArgumentError("weights metadata: no \"skeleton\" object");
  }
  const nlohmann::json& js = metadata["skeleton"];
  Skeleton s;
  const nlohmann::json* parents = js.contains("parents") ? &js["parents"] : nullptr;
  const nlohmann::json* offsets = js.contains("rest_offsets") ? &js["rest_offsets"] : nullptr;
  if (parents == nullptr || !parents->is_array() || parents->size() != kNumJoints) {
    return absl::InvalidArgumentError("weights metadata: skeleton.parents must list 24 joints");
  }
  if (offsets == nullptr || !offsets->is_array() || offsets->size() != kNumJoints) {
    return absl::InvalidArgumentError("weights metadata: skeleton.rest_offsets must list 24 joints");
  }
  for (int j = 0; j < kNumJoints; ++j) {
    const nlohmann::json& p = (*parents)[j];
    const nlohmann::json& o = (*offsets)[j];
    if (!p.is_number_integer()) return absl::InvalidArgumentError("weights metadata: skeleton parent not an int");
    s.parents[j] = p.get<int>();
    if ((j == 0 && s.parents[j] != -1) || (j > 0 && (s.parents[j] < 0 || s.parents[j] >= j))) {
      return absl::InvalidArgumentError(absl::StrCat("weights metadata: skeleton parent of joint ", j, " invalid"));
    }
    if (!o.is_array() || o.size() != 3 || !o[0].is_number() || !o[1].is_number() || !o[2].is_number()) {
      return absl::InvalidArgumentError(absl::StrCat("weights metadata: skeleton offset ", j, " is not [x, y, z]"));
    }
    s.offsets[j] = Eigen::Vector3f(o[0].get<float>(), o[1].get<float>(), o[2].get<float>());
    s.bone_lengths[j] = s.offsets[j].norm();
    if (j > 0) {
      if (!(s.bone_lengths[j] > 1e-6f)) {
        return absl::InvalidArgumentError(absl::StrCat("weights metadata: skeleton bone ", j, " has zero length"));
      }
      s.children[s.parents[j]].push_back(j);
    }
  }
  // The file's canonical lengths (bone projection) override |offset| when present.
  if (js.contains("bone_lengths")) {
    const nlohmann::json& bl = js["bone_lengths"];
    if (!bl.is_array() || bl.size() != kNumJoints) {
      return absl::InvalidArgumentError("weights metadata: skeleton.bone_lengths must list 24 lengths");
    }
    for (int j = 1; j < kNumJoints; ++j) {
      if (!bl[j].is_number() || !(bl[j].get<float>() > 1e-6f)) {
        return absl::InvalidArgumentError(absl::StrCat("weights metadata: skeleton.bone_lengths[", j, "] invalid"));
      }
      s.bone_lengths[j] = bl[j].get<float>();
    }
  }
  if (js.contains("joint_names") && js["joint_names"].is_array() && js["joint_names"].size() == kNumJoints) {
    for (const auto& n : js["joint_names"]) s.joint_names.push_back(n.is_string() ? n.get<std::string>() : "?");
  } else {
    for (const char* n : DefaultJointNames()) s.joint_names.emplace_back(n);
  }
  return s;
}

}  // namespace dance::engine
