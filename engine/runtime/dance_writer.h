// Writers for a whole generated dance: "dance-motion/v1" JSON (docs/model.md section 2, design section 2)
// and BVH (joint rotations, for Blender and game engines).
//
// Usage:
//   DanceInfo info{.model_id = model->model_id(), .seed = 7};
//   absl::Status s = WriteDanceJson("dance.json", model->skeleton(), frames, info);
//   s = WriteBvh("dance.bvh", model->skeleton(), frames);
//
// JSON keys: format, fps, units, up_axis, joint_names, parents, rest_offsets, positions [T][24][3],
// rotations [T][24][4] (w, x, y, z local), upper_codes [T], lower_codes [T], frame_index0,
// audio_offset_s (audio time of positions[0]), model_id, seed, plus the free-form `extra` object.
// BVH: root "pelvis" with 6 channels (Xposition Yposition Zposition Zrotation Xrotation Yrotation), other
// joints 3 rotation channels in the same order, metres, 30 fps, leaves end in an End Site.
//
// Thread safety: pure functions (they write the given file).
#ifndef DANCE_ENGINE_RUNTIME_DANCE_WRITER_H_
#define DANCE_ENGINE_RUNTIME_DANCE_WRITER_H_

#include <string>
#include <vector>

#include "absl/status/status.h"
#include "engine/runtime/session.h"
#include "engine/vq/skeleton.h"
#include "nlohmann/json.hpp"

namespace dance::engine {

struct DanceInfo {
  std::string model_id;
  uint64_t seed = 0;
  nlohmann::json extra = nlohmann::json::object();  // merged into the top level (style, temperature, ...)
};

// The dance-motion/v1 document for `frames` (consecutive, in order).
nlohmann::json DanceJson(const Skeleton& skeleton, const std::vector<PoseFrame>& frames, const DanceInfo& info);
absl::Status WriteDanceJson(const std::string& path, const Skeleton& skeleton,
                            const std::vector<PoseFrame>& frames, const DanceInfo& info);
// BVH text for `frames`.
std::string BvhText(const Skeleton& skeleton, const std::vector<PoseFrame>& frames);
absl::Status WriteBvh(const std::string& path, const Skeleton& skeleton, const std::vector<PoseFrame>& frames);

}  // namespace dance::engine

#endif  // DANCE_ENGINE_RUNTIME_DANCE_WRITER_H_
