// libFuzzer target for the controls' readers (engine/runtime/motion_io.h): BVH, dance-motion/v1 JSON,
// dance-trajectory/v1, dance-mask/v1, and the tracks built from what they accept.
//
// Byte 0 selects the reader (mod 4: BVH, motion JSON, trajectory JSON, mask JSON over a 3-s dance); the
// rest is its text. Invariants: no crash or sanitizer report; accepted motion is finite and within 100 m,
// accepted paths are strictly increasing in time, masks name only the 24 joints, and every accepted input
// passes ValidateControls once made into controls.
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <string>

#include "engine/runtime/controls.h"
#include "engine/runtime/motion_io.h"

namespace {

using namespace dance::engine;  // NOLINT: a fuzz target

void CheckMotion(const MotionFile& m) {
  for (const JointPositions& p : m.positions) {
    for (const Eigen::Vector3f& q : p) {
      if (!q.allFinite() || q.cwiseAbs().maxCoeff() > 100.0f) std::abort();
    }
  }
  Controls c;
  c.motion = CombineTracks(SeedTrack(m.positions, m.first_frame), GivenHalfTrack(m.positions, m.first_frame, true));
  if (!ValidateControls(c).ok()) std::abort();
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 1 || size > (1 << 20)) return 0;
  const std::string text(reinterpret_cast<const char*>(data + 1), size - 1);
  switch (data[0] % 4) {
    case 0: {
      absl::StatusOr<MotionFile> m = ParseBvh(text);
      if (m.ok()) CheckMotion(*m);
      break;
    }
    case 1: {
      absl::StatusOr<MotionFile> m = ParseMotionJson(text);
      if (m.ok()) CheckMotion(*m);
      break;
    }
    case 2: {
      absl::StatusOr<std::vector<TrajectoryPoint>> path = ParseTrajectoryJson(text);
      if (path.ok()) {
        for (size_t i = 1; i < path->size(); ++i) {
          if (!((*path)[i].t_s > (*path)[i - 1].t_s)) std::abort();
        }
        Controls c;
        c.trajectory = *path;
        if (!ValidateControls(c).ok()) std::abort();
      }
      break;
    }
    default: {
      MotionFile dance;
      dance.positions.resize(90);
      dance.offset_s = 1.0;
      dance.first_frame = 30;
      absl::StatusOr<std::vector<JointMask>> mask = ParseMaskJson(text, dance);
      if (mask.ok()) {
        if (mask->size() != dance.positions.size()) std::abort();
        for (JointMask k : *mask) {
          if (k & ~kAllJoints) std::abort();
        }
      }
      break;
    }
  }
  return 0;
}
