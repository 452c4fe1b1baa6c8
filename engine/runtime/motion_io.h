// Readers of the controls' files (docs/controls.md): given motion as dance-motion/v1 JSON or BVH, a
// trajectory (dance-trajectory/v1), an inpainting mask (dance-mask/v1). Motion comes out on the canonical
// 24-joint SMPL skeleton at 30 fps (other frame rates are resampled linearly), placed on the audio timeline
// by its audio_offset_s (JSON) or at 0 (BVH).
//
// Usage:
//   absl::StatusOr<MotionFile> clip = ReadMotionFile("seed.json");        // or .bvh
//   absl::StatusOr<std::vector<TrajectoryPoint>> path = ReadTrajectoryFile("path.json");
//   absl::StatusOr<std::vector<JointMask>> mask = ReadMaskFile("mask.json", *clip);
//
// Errors: NotFound (no file), InvalidArgument naming what is wrong (not JSON/BVH, another format or
// skeleton, a joint count other than 24 or joints missing from a BVH, NaN or absurd positions, times out
// of order, a mask naming unknown joints or times outside the dance). Thread safety: pure functions.
#ifndef DANCE_ENGINE_RUNTIME_MOTION_IO_H_
#define DANCE_ENGINE_RUNTIME_MOTION_IO_H_

#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "engine/runtime/controls.h"

namespace dance::engine {

struct MotionFile {
  std::vector<JointPositions> positions;  // 30 fps
  int64_t first_frame = 0;                // audio frame of positions[0] (round(audio_offset_s x 30))
  double offset_s = 0.0;                  // the file's own audio time of positions[0] (audio_offset_s)
  std::vector<double> times_s;            // keyframe files: each frame's audio time ("times_s"); else empty
};

absl::StatusOr<MotionFile> ReadMotionFile(const std::string& path);
// The text of a file; NotFound if it cannot be read.
absl::StatusOr<std::string> ReadTextFile(const std::string& path);
absl::StatusOr<std::vector<TrajectoryPoint>> ReadTrajectoryFile(const std::string& path);
// The per-frame known joints of `dance` from a dance-mask/v1 file (times on the audio timeline).
absl::StatusOr<std::vector<JointMask>> ReadMaskFile(const std::string& path, const MotionFile& dance);

// The same from text already read (`path` names it in errors): for network input and fuzzing.
absl::StatusOr<MotionFile> ParseMotionJson(const std::string& text);
absl::StatusOr<std::vector<TrajectoryPoint>> ParseTrajectoryJson(const std::string& text,
                                                                 const std::string& path = "trajectory");
absl::StatusOr<std::vector<JointMask>> ParseMaskJson(const std::string& text, const MotionFile& dance,
                                                     const std::string& path = "mask");
// A motion file's text of either kind: BVH if it starts with "HIERARCHY", else dance-motion/v1 JSON;
// `name` names it in errors.
absl::StatusOr<MotionFile> ParseMotionText(const std::string& text, const std::string& name);

// One span of a dance-mask/v1 "known" list: [start_s, end_s) on the audio timeline, joints "all",
// "upper", "lower" or SMPL names.
struct MaskSpan {
  double start_s = 0.0, end_s = 0.0;
  std::vector<std::string> joints;
};
// The "known" list of a dance-mask/v1 text (not yet checked against a dance).
absl::StatusOr<std::vector<MaskSpan>> ParseMaskSpansJson(const std::string& text, const std::string& path = "mask");
// The per-frame known joints of `dance` from mask spans (the "known" list of a dance-mask/v1 file).
absl::StatusOr<std::vector<JointMask>> MaskFromSpans(const std::vector<MaskSpan>& spans, const MotionFile& dance,
                                                     const std::string& path = "mask");

// Parses a BVH text whose joints carry the SMPL joint names (as dance-generate's BVH export writes them).
absl::StatusOr<MotionFile> ParseBvh(const std::string& text);

}  // namespace dance::engine

#endif  // DANCE_ENGINE_RUNTIME_MOTION_IO_H_
