#include "client/export/humanoid.h"

namespace dance::client {

std::vector<int> HumanoidJointIndices(const std::vector<std::string>& joint_names) {
  std::vector<int> out(kHumanoidBones.size(), -1);
  for (size_t b = 0; b < kHumanoidBones.size(); ++b) {
    for (size_t j = 0; j < joint_names.size(); ++j) {
      if (joint_names[j] == kHumanoidBones[b].smpl_name) out[b] = static_cast<int>(j);
    }
  }
  return out;
}

}  // namespace dance::client
