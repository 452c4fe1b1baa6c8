#include "client/export/gltf_writer.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/escaping.h"
#include "absl/strings/str_cat.h"
#include "client/export/humanoid.h"
#include "nlohmann/json.hpp"

namespace dance::client {
namespace {

using nlohmann::json;

constexpr int kFloat = 5126, kUnsignedShort = 5123, kUnsignedByte = 5121;
constexpr int kArrayBuffer = 34962, kElementArrayBuffer = 34963;
constexpr float kBoneHalfWidth = 0.025f;  // the preview mesh's boxes, metres
constexpr float kLeafHalfWidth = 0.04f;

// The binary buffer and the accessors that point into it (one bufferView per accessor).
class BufferBuilder {
 public:
  explicit BufferBuilder(json* doc) : doc_(doc) {
    (*doc_)["bufferViews"] = json::array();
    (*doc_)["accessors"] = json::array();
  }

  // Appends raw bytes as a bufferView and an accessor over them; returns the accessor's index.
  int Add(const void* data, size_t bytes, int component_type, const char* type, size_t count, int target,
          json min = nullptr, json max = nullptr) {
    while (bin_.size() % 4 != 0) bin_.push_back('\0');
    json view = {{"buffer", 0}, {"byteOffset", bin_.size()}, {"byteLength", bytes}};
    if (target != 0) view["target"] = target;
    bin_.append(static_cast<const char*>(data), bytes);
    (*doc_)["bufferViews"].push_back(view);
    json acc = {{"bufferView", (*doc_)["bufferViews"].size() - 1},
                {"componentType", component_type},
                {"count", count},
                {"type", type}};
    if (!min.is_null()) acc["min"] = min;
    if (!max.is_null()) acc["max"] = max;
    (*doc_)["accessors"].push_back(acc);
    return static_cast<int>((*doc_)["accessors"].size() - 1);
  }

  int AddFloats(const std::vector<float>& v, const char* type, int width, int target, bool bounds = false) {
    json min = nullptr, max = nullptr;
    if (bounds) {
      min = json::array();
      max = json::array();
      for (int k = 0; k < width; ++k) {
        float lo = v[k], hi = v[k];
        for (size_t i = k; i < v.size(); i += width) {
          lo = std::min(lo, v[i]);
          hi = std::max(hi, v[i]);
        }
        min.push_back(lo);
        max.push_back(hi);
      }
    }
    return Add(v.data(), v.size() * sizeof(float), kFloat, type, v.size() / width, target, min, max);
  }

  std::string& bin() { return bin_; }

 private:
  json* doc_;
  std::string bin_;
};

// The preview mesh: boxes along the bones, skinned rigidly.
struct PreviewMesh {
  std::vector<float> positions;    // (V, 3)
  std::vector<uint8_t> joints;     // (V, 4)
  std::vector<float> weights;      // (V, 4)
  std::vector<uint16_t> indices;   // (3 * triangles)
};

// A box of half-width `half` from a to b (a cube of side 2 half centred on a when they coincide).
void AddBox(Vec3 a, const Vec3& b, float half, int joint, PreviewMesh* m) {
  Vec3 d{b[0] - a[0], b[1] - a[1], b[2] - a[2]};
  float len = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
  Vec3 u, v;
  if (len < 1e-6f) {
    d = {0, 1, 0};
    len = 2 * half;
    a[1] -= half;
  } else {
    for (float& x : d) x /= len;
  }
  const Vec3 ref = std::abs(d[1]) < 0.9f ? Vec3{0, 1, 0} : Vec3{1, 0, 0};
  u = {d[1] * ref[2] - d[2] * ref[1], d[2] * ref[0] - d[0] * ref[2], d[0] * ref[1] - d[1] * ref[0]};
  const float un = std::sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2]);
  for (float& x : u) x /= un;
  v = {d[1] * u[2] - d[2] * u[1], d[2] * u[0] - d[0] * u[2], d[0] * u[1] - d[1] * u[0]};
  const uint16_t base = static_cast<uint16_t>(m->positions.size() / 3);
  for (int end = 0; end < 2; ++end) {
    for (int corner = 0; corner < 4; ++corner) {
      const float su = (corner & 1) ? half : -half, sv = (corner & 2) ? half : -half;
      for (int k = 0; k < 3; ++k) m->positions.push_back(a[k] + end * len * d[k] + su * u[k] + sv * v[k]);
      m->joints.insert(m->joints.end(), {static_cast<uint8_t>(joint), 0, 0, 0});
      m->weights.insert(m->weights.end(), {1.0f, 0.0f, 0.0f, 0.0f});
    }
  }
  // Corners 0..3 at the start, 4..7 at the end; (0,1,3,2) is the cap's loop.
  static constexpr uint16_t kFaces[12][3] = {{0, 2, 1}, {1, 2, 3}, {4, 5, 6}, {5, 7, 6}, {0, 1, 4}, {1, 5, 4},
                                             {1, 3, 5}, {3, 7, 5}, {3, 2, 7}, {2, 6, 7}, {2, 0, 6}, {0, 4, 6}};
  for (const auto& f : kFaces) {
    for (uint16_t i : f) m->indices.push_back(base + i);
  }
}

PreviewMesh BuildPreviewMesh(const MotionClip& clip, const std::vector<Vec3>& rest) {
  PreviewMesh m;
  const int n = clip.num_joints();
  std::vector<int> children(n, 0);
  for (int j = 1; j < n; ++j) ++children[clip.parents[j]];
  for (int j = 1; j < n; ++j) AddBox(rest[clip.parents[j]], rest[j], kBoneHalfWidth, clip.parents[j], &m);
  for (int j = 0; j < n; ++j) {
    if (children[j] == 0) AddBox(rest[j], rest[j], kLeafHalfWidth, j, &m);
  }
  return m;
}

std::string Pad(std::string s, char fill) {
  while (s.size() % 4 != 0) s.push_back(fill);
  return s;
}

void AppendU32(std::string* out, uint32_t v) {
  for (int k = 0; k < 4; ++k) out->push_back(static_cast<char>((v >> (8 * k)) & 0xff));
}

}  // namespace

bool GltfKindForPath(const std::string& path, GltfKind* kind) {
  const std::string lower = absl::AsciiStrToLower(path);
  auto ends = [&](const char* ext) {
    const size_t n = std::strlen(ext);
    return lower.size() > n && lower.compare(lower.size() - n, n, ext) == 0;
  };
  if (ends(".glb")) {
    *kind = GltfKind::kGlb;
  } else if (ends(".gltf")) {
    *kind = GltfKind::kGltf;
  } else if (ends(".vrma")) {
    *kind = GltfKind::kVrma;
  } else {
    return false;
  }
  return true;
}

absl::StatusOr<std::string> MotionToGltf(const MotionClip& clip, GltfKind kind) {
  if (absl::Status s = ValidateClip(clip); !s.ok()) return s;
  if (clip.num_frames() == 0) return absl::InvalidArgumentError("glTF export: the dance has no frames");
  const int n = clip.num_joints();
  const int64_t frames = clip.num_frames();
  const bool vrma = kind == GltfKind::kVrma;
  const std::vector<Vec3> rest = RestPositions(clip);
  float lowest = 0.0f;
  for (const Vec3& p : rest) lowest = std::min(lowest, p[1]);

  json doc = {{"asset",
               {{"version", "2.0"},
                {"generator", "dance (client/export/gltf_writer.cc)"},
                {"extras", {{"fps", clip.fps}, {"frames", frames}}}}},
              {"scene", 0}};
  BufferBuilder buf(&doc);

  // Nodes: 0 = "dance", 1 + j = joint j.
  json nodes = json::array();
  json top = {{"name", "dance"}, {"children", json::array({1})}};
  nodes.push_back(top);
  for (int j = 0; j < n; ++j) {
    json node = {{"name", clip.joint_names[j]}};
    const Vec3 t = j == 0 ? Vec3{0.0f, -lowest, 0.0f} : clip.rest_offsets[j];
    node["translation"] = {t[0], t[1], t[2]};
    json children = json::array();
    for (int c = j + 1; c < n; ++c) {
      if (clip.parents[c] == j) children.push_back(1 + c);
    }
    if (!children.empty()) node["children"] = children;
    nodes.push_back(node);
  }

  if (!vrma) {
    const PreviewMesh m = BuildPreviewMesh(clip, rest);
    // The mesh is modelled at the rest pose with the root at its rest translation.
    std::vector<float> positions = m.positions;
    for (size_t i = 1; i < positions.size(); i += 3) positions[i] -= lowest;
    const int pos = buf.AddFloats(positions, "VEC3", 3, kArrayBuffer, /*bounds=*/true);
    const int jnt = buf.Add(m.joints.data(), m.joints.size(), kUnsignedByte, "VEC4", m.joints.size() / 4, kArrayBuffer);
    const int wgt = buf.AddFloats(m.weights, "VEC4", 4, kArrayBuffer);
    const int idx = buf.Add(m.indices.data(), m.indices.size() * 2, kUnsignedShort, "SCALAR", m.indices.size(),
                            kElementArrayBuffer);
    doc["meshes"] = json::array({{{"name", "bones"},
                                  {"primitives",
                                   json::array({{{"attributes", {{"POSITION", pos}, {"JOINTS_0", jnt}, {"WEIGHTS_0", wgt}}},
                                                 {"indices", idx},
                                                 {"material", 0}}})}}});
    doc["materials"] = json::array(
        {{{"name", "body"}, {"pbrMetallicRoughness", {{"baseColorFactor", {0.8, 0.8, 0.85, 1.0}}, {"metallicFactor", 0.0}}}}});
    // Inverse bind matrices: the rest global transforms are translations, so their inverses are too.
    std::vector<float> ibm;
    for (int j = 0; j < n; ++j) {
      const float m16[16] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, -rest[j][0], -(rest[j][1] - lowest), -rest[j][2], 1};
      ibm.insert(ibm.end(), m16, m16 + 16);
    }
    const int ibm_acc = buf.AddFloats(ibm, "MAT4", 16, 0);
    json joints = json::array();
    for (int j = 0; j < n; ++j) joints.push_back(1 + j);
    doc["skins"] = json::array({{{"name", "skeleton"}, {"joints", joints}, {"skeleton", 1}, {"inverseBindMatrices", ibm_acc}}});
    nodes.push_back({{"name", "body"}, {"mesh", 0}, {"skin", 0}});
    nodes[0]["children"].push_back(static_cast<int>(nodes.size() - 1));
  }
  doc["nodes"] = nodes;
  doc["scenes"] = json::array({{{"name", "dance"}, {"nodes", json::array({0})}}});

  // Animation.
  std::vector<float> times(frames);
  for (int64_t t = 0; t < frames; ++t) times[t] = static_cast<float>(t / clip.fps);
  const int time_acc = buf.AddFloats(times, "SCALAR", 1, 0, /*bounds=*/true);
  json samplers = json::array(), channels = json::array();
  std::vector<float> root(frames * 3);
  for (int64_t t = 0; t < frames; ++t) {
    for (int k = 0; k < 3; ++k) root[3 * t + k] = clip.root_positions[t][k];
  }
  samplers.push_back({{"input", time_acc}, {"output", buf.AddFloats(root, "VEC3", 3, 0)}, {"interpolation", "LINEAR"}});
  channels.push_back({{"sampler", 0}, {"target", {{"node", 1}, {"path", "translation"}}}});
  for (int j = 0; j < n; ++j) {
    std::vector<float> q(frames * 4);
    for (int64_t t = 0; t < frames; ++t) {
      const Quat& r = clip.rotation(t, j);
      q[4 * t] = r[1];
      q[4 * t + 1] = r[2];
      q[4 * t + 2] = r[3];
      q[4 * t + 3] = r[0];
    }
    samplers.push_back({{"input", time_acc}, {"output", buf.AddFloats(q, "VEC4", 4, 0)}, {"interpolation", "LINEAR"}});
    channels.push_back({{"sampler", samplers.size() - 1}, {"target", {{"node", 1 + j}, {"path", "rotation"}}}});
  }
  doc["animations"] = json::array({{{"name", "dance"}, {"samplers", samplers}, {"channels", channels}}});

  if (vrma) {
    json bones = json::object();
    const std::vector<int> joint = HumanoidJointIndices(clip.joint_names);
    for (size_t b = 0; b < kHumanoidBones.size(); ++b) {
      if (joint[b] >= 0) bones[kHumanoidBones[b].vrm_name] = {{"node", 1 + joint[b]}};
    }
    if (!bones.contains("hips")) return absl::InvalidArgumentError("VRMA export: the skeleton has no 'pelvis'");
    doc["extensionsUsed"] = json::array({"VRMC_vrm_animation"});
    doc["extensions"] = {{"VRMC_vrm_animation", {{"specVersion", "1.0"}, {"humanoid", {{"humanBones", bones}}}}}};
  }

  std::string& bin = buf.bin();
  while (bin.size() % 4 != 0) bin.push_back('\0');
  if (kind == GltfKind::kGltf) {
    doc["buffers"] = json::array(
        {{{"byteLength", bin.size()}, {"uri", absl::StrCat("data:application/octet-stream;base64,", absl::Base64Escape(bin))}}});
    return doc.dump(1);
  }
  doc["buffers"] = json::array({{{"byteLength", bin.size()}}});
  const std::string text = Pad(doc.dump(), ' ');
  std::string out = "glTF";
  AppendU32(&out, 2);
  AppendU32(&out, static_cast<uint32_t>(12 + 8 + text.size() + 8 + bin.size()));
  AppendU32(&out, static_cast<uint32_t>(text.size()));
  out += "JSON";
  out += text;
  AppendU32(&out, static_cast<uint32_t>(bin.size()));
  out.append("BIN\0", 4);
  out += bin;
  return out;
}

absl::Status WriteMotionFile(const std::string& path, const MotionClip& clip) {
  GltfKind kind;
  if (!GltfKindForPath(path, &kind)) {
    return absl::InvalidArgumentError(absl::StrCat("'", path, "': not .glb, .gltf or .vrma"));
  }
  absl::StatusOr<std::string> bytes = MotionToGltf(clip, kind);
  if (!bytes.ok()) return bytes.status();
  std::ofstream out(path, std::ios::binary);
  if (!out) return absl::PermissionDeniedError(absl::StrCat("cannot write ", path));
  out << *bytes;
  out.close();
  if (!out) return absl::DataLossError(absl::StrCat("write failed: ", path));
  return absl::OkStatus();
}

}  // namespace dance::client
