// Saving a received dance: "dance-motion/v1" JSON (the project's exchange format) and BVH (for Blender and
// game engines).
//
// dance-motion/v1: {"format": "dance-motion/v1", "fps": 30, "units": "m", "up_axis": "y",
//   "joint_names": [24], "parents": [24], "rest_offsets": [24][3], "positions": [T][24][3],
//   "rotations": [T][24][4] (w, x, y, z, local), "audio_offset_s": time of the first frame,
//   "codes": {"upper": [T], "lower": [T]}, "model_id", "seed", "session_id"}.
// BVH: the skeleton from rest offsets (centimetres), root channels Xposition Yposition Zposition Zrotation
//   Xrotation Yrotation, other joints Zrotation Xrotation Yrotation (degrees, R = Rz Rx Ry), one MOTION row
//   per frame; G_j = G_parent L_j as in docs/rotations.md, so forward kinematics reproduces the positions.
//
// glTF 2.0 / VRM Animation: the same dance through MotionClip (client/export/gltf_writer.h); WriteDanceFile
//   picks the format by the path's extension (.json, .bvh, .glb, .gltf, .vrma).
//
// Thread safety: pure functions.
#ifndef DANCE_CLIENT_DANCE_FILE_H_
#define DANCE_CLIENT_DANCE_FILE_H_

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "client/export/motion_clip.h"
#include "dance/v1/dance.pb.h"
#include "nlohmann/json.hpp"

namespace dance::client {

// beat_times_s: the stream's KIND_BEAT times (s, audio timeline), written as "beat_times_s" when not empty.
nlohmann::json DanceToJson(const dance::v1::SessionInfo& info, const std::vector<dance::v1::PoseFrame>& frames,
                           uint64_t seed, const std::vector<double>& beat_times_s = {});
absl::Status WriteDanceJson(const std::string& path, const dance::v1::SessionInfo& info,
                            const std::vector<dance::v1::PoseFrame>& frames, uint64_t seed,
                            const std::vector<double>& beat_times_s = {});
std::string DanceToBvh(const dance::v1::SessionInfo& info, const std::vector<dance::v1::PoseFrame>& frames);
absl::Status WriteBvh(const std::string& path, const dance::v1::SessionInfo& info,
                      const std::vector<dance::v1::PoseFrame>& frames);

// The stream's skeleton and frames as a MotionClip (root = positions[0]; frames without rotations get
// identity rotations).
MotionClip ClipFromStream(const dance::v1::SessionInfo& info, const std::vector<dance::v1::PoseFrame>& frames);
// Writes the dance in the format the extension names: .json (dance-motion/v1, with the beats), .bvh, .glb,
// .gltf, .vrma.
absl::Status WriteDanceFile(const std::string& path, const dance::v1::SessionInfo& info,
                            const std::vector<dance::v1::PoseFrame>& frames, uint64_t seed,
                            const std::vector<double>& beat_times_s = {});
// The beat times (s) of a stream's events (KIND_BEAT), in order.
std::vector<double> BeatTimesOf(const std::vector<dance::v1::Event>& events);
// Reads a dance-motion/v1 JSON file back as SessionInfo (skeleton, fps, model and session ids) and frames
// (index, time_ms, positions, rotations, codes); InvalidArgument when it is not one.
absl::Status ReadDanceJson(const std::string& path, dance::v1::SessionInfo* info,
                           std::vector<dance::v1::PoseFrame>* frames);

// Euler angles (degrees) for BVH channel order Z, X, Y of the unit quaternion (w, x, y, z): R = Rz Rx Ry.
std::array<double, 3> QuaternionToEulerZXY(double w, double x, double y, double z);

}  // namespace dance::client

#endif  // DANCE_CLIENT_DANCE_FILE_H_
