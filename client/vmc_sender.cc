#include "client/vmc_sender.h"

#include <lo/lo.h>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "client/export/humanoid.h"

namespace dance::client {

Vec3 ToUnityPosition(const Vec3& p) { return {-p[0], p[1], p[2]}; }

// A mirror in X maps a rotation about axis a by angle t to one about (a.x, -a.y, -a.z) by the same t.
std::array<float, 4> ToUnityRotation(const Quat& q) { return {q[1], -q[2], -q[3], q[0]}; }

absl::Status ParseVmcTarget(const std::string& target, std::string* host, int* port) {
  *port = kVmcDefaultPort;
  std::string port_text;
  if (!target.empty() && target[0] == '[') {
    const size_t close = target.find(']');
    if (close == std::string::npos) return absl::InvalidArgumentError(absl::StrCat("bad VMC address '", target, "'"));
    *host = target.substr(1, close - 1);
    if (close + 1 < target.size()) {
      if (target[close + 1] != ':') return absl::InvalidArgumentError(absl::StrCat("bad VMC address '", target, "'"));
      port_text = target.substr(close + 2);
    }
  } else {
    const size_t colon = target.rfind(':');
    *host = target.substr(0, colon);
    if (colon != std::string::npos) port_text = target.substr(colon + 1);
  }
  if (host->empty()) return absl::InvalidArgumentError(absl::StrCat("VMC address '", target, "' has no host"));
  if (!port_text.empty() && (!absl::SimpleAtoi(port_text, port) || *port < 1 || *port > 65535)) {
    return absl::InvalidArgumentError(absl::StrCat("bad VMC port in '", target, "'"));
  }
  return absl::OkStatus();
}

absl::StatusOr<std::unique_ptr<VmcSender>> VmcSender::Create(const std::string& target, const MotionClip& skeleton,
                                                             VmcOptions options) {
  std::string host;
  int port = 0;
  if (absl::Status s = ParseVmcTarget(target, &host, &port); !s.ok()) return s;
  if (skeleton.joint_names.size() != skeleton.parents.size() ||
      skeleton.rest_offsets.size() != skeleton.parents.size()) {
    return absl::InvalidArgumentError("VMC: skeleton names, parents and rest offsets differ in length");
  }
  const std::vector<int> joints = HumanoidJointIndices(skeleton.joint_names);
  if (joints[0] != 0) return absl::InvalidArgumentError("VMC: the skeleton's root joint is not 'pelvis'");
  const std::string port_text = std::to_string(port);
  lo_address a = lo_address_new(host.c_str(), port_text.c_str());
  if (a == nullptr) return absl::InvalidArgumentError(absl::StrCat("VMC: cannot resolve '", host, "'"));
  return std::unique_ptr<VmcSender>(new VmcSender(a, skeleton, options));
}

VmcSender::VmcSender(lo_address address, const MotionClip& skeleton, VmcOptions options)
    : address_(address), options_(options), rest_offsets_(skeleton.rest_offsets) {
  const std::vector<int> joints = HumanoidJointIndices(skeleton.joint_names);
  for (size_t b = 0; b < kHumanoidBones.size(); ++b) {
    if (joints[b] < 0) continue;
    bone_names_.push_back(kHumanoidBones[b].unity_name);
    bone_joints_.push_back(joints[b]);
  }
}

VmcSender::~VmcSender() { lo_address_free(address_); }

absl::Status VmcSender::Send(const Vec3& root_position, const Quat* rotations, double time_s) {
  // Messages are built first and sent either as one bundle or one by one.
  std::vector<std::pair<const char*, lo_message>> messages;
  messages.reserve(3 + bone_joints_.size());
  lo_message ok = lo_message_new();
  lo_message_add_int32(ok, 1);
  lo_message_add_int32(ok, 3);
  lo_message_add_int32(ok, 0);
  messages.emplace_back("/VMC/Ext/OK", ok);
  lo_message t = lo_message_new();
  lo_message_add_float(t, static_cast<float>(time_s));
  messages.emplace_back("/VMC/Ext/T", t);
  lo_message root = lo_message_new();
  lo_message_add_string(root, "root");
  for (float v : {0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 1.0f}) lo_message_add_float(root, v);
  messages.emplace_back("/VMC/Ext/Root/Pos", root);
  for (size_t b = 0; b < bone_joints_.size(); ++b) {
    const int j = bone_joints_[b];
    const Vec3 p = ToUnityPosition(j == 0 ? root_position : rest_offsets_[j]);
    const std::array<float, 4> q = ToUnityRotation(rotations[j]);
    lo_message m = lo_message_new();
    lo_message_add_string(m, bone_names_[b]);
    for (float v : p) lo_message_add_float(m, v);
    for (float v : q) lo_message_add_float(m, v);
    messages.emplace_back("/VMC/Ext/Bone/Pos", m);
  }
  bool failed = false;
  if (options_.bundle) {
    lo_bundle bundle = lo_bundle_new(LO_TT_IMMEDIATE);
    for (auto& [path, m] : messages) lo_bundle_add_message(bundle, path, m);
    failed = lo_send_bundle(address_, bundle) < 0;
    lo_bundle_free_recursive(bundle);  // frees the messages too
    ++datagrams_sent_;
  } else {
    for (auto& [path, m] : messages) {
      failed = lo_send_message(address_, path, m) < 0 || failed;
      lo_message_free(m);
      ++datagrams_sent_;
    }
  }
  if (failed) {
    return absl::UnavailableError(absl::StrCat("VMC send failed: ", lo_address_errstr(address_)));
  }
  ++frames_sent_;
  return absl::OkStatus();
}

}  // namespace dance::client
