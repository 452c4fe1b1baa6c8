// glTF 2.0 writers for a MotionClip: a skinned skeleton with the dance as its animation (.glb binary or
// .gltf text with the buffer embedded), for Blender, three.js, game engines and any glTF viewer; and VRM
// Animation (.vrma: a .glb with the VRMC_vrm_animation extension, specVersion 1.0) that VRM apps and
// @pixiv/three-vrm-animation play on any VRM avatar.
//
// The file: one node per joint (named as the skeleton's joints, parented as it, rest translation = the
// rest offset, rest rotation = identity; the root's rest translation puts the rest pose's lowest joint on
// the floor), under a node "dance". The glTF kinds add a mesh skinned to those joints (a box along every
// bone, weighted to the bone's parent joint, a cube at every leaf) so a viewer shows the body; the VRMA
// maps the 22 humanoid bones (client/export/humanoid.h) to their nodes instead. One animation "dance":
// per joint a rotation channel (the local rotations, glTF's x, y, z, w), and the root's translation (its
// world position), LINEAR samplers, times from 0 at the clip's fps. Y up, metres, facing +Z with the
// body's left at +X: glTF's and VRM 1.0's frame, so no axis conversion. asset.extras records fps and
// frames.
//
// Usage:
//   absl::Status s = WriteMotionFile("dance.glb", clip);       // kind from the extension (.glb .gltf .vrma)
//   absl::StatusOr<std::string> bytes = MotionToGltf(clip, GltfKind::kVrma);
//
// Errors: InvalidArgument for an invalid clip, no frames, or an unknown extension; PermissionDenied /
// DataLoss when the file cannot be written.
// Thread safety: pure functions.
#ifndef DANCE_CLIENT_EXPORT_GLTF_WRITER_H_
#define DANCE_CLIENT_EXPORT_GLTF_WRITER_H_

#include <string>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "client/export/motion_clip.h"

namespace dance::client {

enum class GltfKind {
  kGlb,   // binary glTF, skinned mesh + animation
  kGltf,  // text glTF, the buffer as a base64 data URI
  kVrma,  // binary glTF with VRMC_vrm_animation, no mesh
};

// The file's bytes.
absl::StatusOr<std::string> MotionToGltf(const MotionClip& clip, GltfKind kind);
// Kind by the path's extension (case-insensitive): .glb, .gltf, .vrma; false for anything else.
bool GltfKindForPath(const std::string& path, GltfKind* kind);
// Writes `clip` to `path` in the kind its extension names.
absl::Status WriteMotionFile(const std::string& path, const MotionClip& clip);

}  // namespace dance::client

#endif  // DANCE_CLIENT_EXPORT_GLTF_WRITER_H_
