// PoseFrame: one frame of a dance as the engine emits it (docs/model.md section 2).
#ifndef DANCE_ENGINE_RUNTIME_POSE_FRAME_H_
#define DANCE_ENGINE_RUNTIME_POSE_FRAME_H_

#include <array>
#include <cstdint>

#include "Eigen/Core"
#include "Eigen/Geometry"

namespace dance::engine {

struct PoseFrame {
  int64_t index = 0;     // pose frame index since stream start (30 fps)
  double time_s = 0.0;   // audio time of this frame's start, seconds on the input timeline (index / 30)
  std::array<Eigen::Vector3f, 24> positions;     // metres, Y up, SMPL order, bone lengths canonical
  std::array<Eigen::Quaternionf, 24> rotations;  // local joint rotations (relative to the parent's frame)
  int upper_code = 0;
  int lower_code = 0;
};

}  // namespace dance::engine

#endif  // DANCE_ENGINE_RUNTIME_POSE_FRAME_H_
