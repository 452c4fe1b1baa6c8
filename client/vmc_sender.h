// VmcSender: sends poses as the VMC protocol (OSC over UDP, https://protocol.vmc.info) to a Marionette
// (VSeeFace, VirtualMotionCapture, VNyan, Warudo, EVMC4U, VMC4UE, ...; they listen on 39539 by default),
// through liblo. One frame is:
//   /VMC/Ext/OK        (int) 1 loaded, (int) 3 calibrated, (int) 0 normal mode
//   /VMC/Ext/T         (float) the frame's audio time, s
//   /VMC/Ext/Root/Pos  (string) "root", position 0 0 0, rotation 0 0 0 1 (the avatar's root stays put)
//   /VMC/Ext/Bone/Pos  (string) HumanBodyBones name, (float) p.x p.y p.z q.x q.y q.z q.w   per humanoid bone
// Bone positions and rotations are local (relative to the parent bone), in Unity's left-handed frame
// (X right, Y up, Z forward; the avatar faces +Z): ours is right-handed with the body's left at +X, so
// p_unity = (-x, y, z) and q_unity = (x, -y, -z, w) for our q = (w, x, y, z). Hips carries the dancer's
// position (the pelvis in world space, metres) and its global rotation; every other bone its SMPL rest
// offset as position (receivers that copy bone positions get SMPL's proportions) and its local rotation.
// The rest pose (all rotations identity) is SMPL's, close to a T-pose (arms level), which is also the
// rest of a normalised VRM/Unity humanoid. Bones: client/export/humanoid.h (22; SMPL's hand ends have none).
//
// Packets: by default a frame is one OSC bundle (timetag "immediately"); VmcOptions::bundle = false sends
// every message as its own datagram (some receivers read only plain messages).
//
// Usage:
//   auto vmc = VmcSender::Create("192.168.1.20:39539", clip /* skeleton */, {});
//   if (!vmc.ok()) return vmc.status();
//   absl::Status s = (*vmc)->Send(root_position, rotations.data(), time_s);   // rotations: J x (w, x, y, z)
//
// Errors: Create returns InvalidArgument for a bad address or a skeleton without a pelvis, Send returns
// Unavailable when the datagram could not be sent (UDP gives no delivery guarantee either way).
// Thread safety: one thread per sender.
#ifndef DANCE_CLIENT_VMC_SENDER_H_
#define DANCE_CLIENT_VMC_SENDER_H_

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "client/export/motion_clip.h"

typedef void* lo_address;  // liblo's opaque handle (lo/lo_types.h)

namespace dance::client {

inline constexpr int kVmcDefaultPort = 39539;

struct VmcOptions {
  bool bundle = true;  // one bundle per frame; false: one message per datagram
};

// Our frame to Unity's (see above). Rotations come back as (x, y, z, w), VMC's order.
Vec3 ToUnityPosition(const Vec3& p);
std::array<float, 4> ToUnityRotation(const Quat& q_wxyz);

// "HOST", "HOST:PORT" or "[IPv6]:PORT" -> host and port (default kVmcDefaultPort).
absl::Status ParseVmcTarget(const std::string& target, std::string* host, int* port);

class VmcSender {
 public:
  // `skeleton`: joint_names, parents and rest_offsets are used (frames are ignored).
  static absl::StatusOr<std::unique_ptr<VmcSender>> Create(const std::string& target, const MotionClip& skeleton,
                                                           VmcOptions options);
  ~VmcSender();
  VmcSender(const VmcSender&) = delete;
  VmcSender& operator=(const VmcSender&) = delete;

  // Sends one frame: the root joint's world position and the J local rotations (w, x, y, z).
  absl::Status Send(const Vec3& root_position, const Quat* rotations, double time_s);

  int64_t frames_sent() const { return frames_sent_; }
  int64_t datagrams_sent() const { return datagrams_sent_; }
  int bones() const { return static_cast<int>(bone_names_.size()); }
  int num_joints() const { return static_cast<int>(rest_offsets_.size()); }

 private:
  VmcSender(lo_address address, const MotionClip& skeleton, VmcOptions options);

  lo_address address_;
  const VmcOptions options_;
  std::vector<const char*> bone_names_;  // HumanBodyBones names of the bones sent
  std::vector<int> bone_joints_;         // their joint indices, parents first; bone_joints_[0] = the root
  std::vector<Vec3> rest_offsets_;       // per joint
  int64_t frames_sent_ = 0;
  int64_t datagrams_sent_ = 0;
};

}  // namespace dance::client

#endif  // DANCE_CLIENT_VMC_SENDER_H_
