// The glTF 2.0 / VRMA writers, read back the way an importer reads them: GLB header and chunks, the JSON's
// node tree, skin and animation, the accessor data out of the binary chunk; forward kinematics of the
// nodes' rest translations and the animated rotations/translation must reproduce the clip's poses.
#include <cstring>
#include <map>
#include <string>

#include "absl/strings/escaping.h"
#include "absl/strings/match.h"
#include "client/export/gltf_writer.h"
#include "client/export/humanoid.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "tests/client/smpl_test_clip.h"

namespace dance::client {
namespace {

using nlohmann::json;

uint32_t U32(const std::string& s, size_t at) {
  uint32_t v;
  std::memcpy(&v, s.data() + at, 4);
  return v;
}

struct Gltf {
  json doc;
  std::string bin;

  // The float data of an accessor (tightly packed, as the writer makes them).
  std::vector<float> Floats(int accessor) const {
    const json& a = doc["accessors"][accessor];
    const json& v = doc["bufferViews"][a["bufferView"].get<int>()];
    EXPECT_EQ(a["componentType"], 5126);
    std::vector<float> out(v["byteLength"].get<size_t>() / 4);
    std::memcpy(out.data(), bin.data() + v["byteOffset"].get<size_t>(), out.size() * 4);
    return out;
  }
};

Gltf ParseGlb(const std::string& b) {
  Gltf g;
  EXPECT_EQ(b.substr(0, 4), "glTF");
  EXPECT_EQ(U32(b, 4), 2u);
  EXPECT_EQ(U32(b, 8), b.size());
  const uint32_t json_len = U32(b, 12);
  EXPECT_EQ(b.substr(16, 4), "JSON");
  EXPECT_EQ(json_len % 4, 0u);
  g.doc = json::parse(b.substr(20, json_len));
  const size_t bin_at = 20 + json_len;
  const uint32_t bin_len = U32(b, bin_at);
  EXPECT_EQ(b.substr(bin_at + 4, 4), std::string("BIN\0", 4));
  EXPECT_EQ(bin_at + 8 + bin_len, b.size());
  g.bin = b.substr(bin_at + 8, bin_len);
  EXPECT_EQ(g.doc["buffers"][0]["byteLength"].get<size_t>(), g.bin.size());
  return g;
}

// FK over the file's nodes at animation key t: joint node j is node 1 + j (the writer's layout, checked
// by name below). Returns world positions of the joint nodes.
std::vector<Vec3> NodeFk(const Gltf& g, int joints, int64_t t) {
  std::map<int, Quat> rot;   // node -> (w, x, y, z)
  std::map<int, Vec3> trans;
  for (const json& ch : g.doc["animations"][0]["channels"]) {
    const json& s = g.doc["animations"][0]["samplers"][ch["sampler"].get<int>()];
    const std::vector<float> out = g.Floats(s["output"]);
    const int node = ch["target"]["node"];
    if (ch["target"]["path"] == "rotation") {
      rot[node] = {out[4 * t + 3], out[4 * t], out[4 * t + 1], out[4 * t + 2]};
    } else {
      trans[node] = {out[3 * t], out[3 * t + 1], out[3 * t + 2]};
    }
  }
  std::vector<Quat> global(joints + 1, Quat{1, 0, 0, 0});
  std::vector<Vec3> pos(joints + 1, Vec3{0, 0, 0});
  // Parents from the children lists; nodes are numbered parents first.
  std::map<int, int> parent;
  for (size_t n = 0; n < g.doc["nodes"].size(); ++n) {
    for (const json& c : g.doc["nodes"][n].value("children", json::array())) parent[c.get<int>()] = static_cast<int>(n);
  }
  for (int n = 1; n <= joints; ++n) {
    const json& node = g.doc["nodes"][n];
    Vec3 tr{node["translation"][0], node["translation"][1], node["translation"][2]};
    if (trans.count(n)) tr = trans[n];
    const Quat r = rot.count(n) ? rot[n] : Quat{1, 0, 0, 0};
    const int p = parent.at(n);
    const Vec3 d = QuatRotate(global[p], tr);
    pos[n] = {pos[p][0] + d[0], pos[p][1] + d[1], pos[p][2] + d[2]};
    global[n] = QuatMul(global[p], r);
  }
  return std::vector<Vec3>(pos.begin() + 1, pos.end());
}

void ExpectAnimationReproducesClip(const Gltf& g, const MotionClip& clip) {
  const json& anim = g.doc["animations"][0];
  EXPECT_EQ(anim["channels"].size(), static_cast<size_t>(clip.num_joints() + 1));
  const std::vector<float> times = g.Floats(anim["samplers"][0]["input"]);
  ASSERT_EQ(times.size(), static_cast<size_t>(clip.num_frames()));
  EXPECT_FLOAT_EQ(times[1], 1.0f / 30.0f);
  EXPECT_FLOAT_EQ(g.doc["accessors"][anim["samplers"][0]["input"].get<int>()]["max"][0].get<float>(), times.back());
  for (int64_t t = 0; t < clip.num_frames(); ++t) {
    const std::vector<Vec3> got = NodeFk(g, clip.num_joints(), t), want = GlobalPositions(clip, t);
    for (int j = 0; j < clip.num_joints(); ++j) {
      for (int k = 0; k < 3; ++k) ASSERT_NEAR(got[j][k], want[j][k], 1e-5f) << clip.joint_names[j] << " t " << t;
    }
  }
}

TEST(GltfWriter, GlbHasASkinnedSkeletonAndTheDance) {
  const MotionClip clip = testing::RandomDance(20, 1);
  absl::StatusOr<std::string> bytes = MotionToGltf(clip, GltfKind::kGlb);
  ASSERT_TRUE(bytes.ok()) << bytes.status();
  const Gltf g = ParseGlb(*bytes);
  const json& nodes = g.doc["nodes"];
  for (int j = 0; j < clip.num_joints(); ++j) EXPECT_EQ(nodes[1 + j]["name"], clip.joint_names[j]);
  ASSERT_EQ(g.doc["skins"].size(), 1u);
  const json& skin = g.doc["skins"][0];
  ASSERT_EQ(skin["joints"].size(), 24u);
  // Inverse bind matrices undo each joint's rest world transform (FK at rest, root at its rest height).
  const std::vector<float> ibm = g.Floats(skin["inverseBindMatrices"]);
  MotionClip rest = testing::SmplSkeleton();
  rest.root_positions.push_back({0, nodes[1]["translation"][1].get<float>(), 0});
  rest.rotations.assign(24, Quat{1, 0, 0, 0});
  const std::vector<Vec3> rest_world = GlobalPositions(rest, 0);
  for (int j = 0; j < 24; ++j) {
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(ibm[16 * j + 12 + k], -rest_world[j][k], 1e-6f);
    EXPECT_FLOAT_EQ(ibm[16 * j], 1.0f);
  }
  // The rest pose stands on the floor: the lowest joint at y = 0.
  float lowest = 1e9f;
  for (const Vec3& p : rest_world) lowest = std::min(lowest, p[1]);
  EXPECT_NEAR(lowest, 0.0f, 1e-6f);
  // A mesh skinned to the joints: every vertex weighted 1 to a valid joint, positions bounded.
  const json& prim = g.doc["meshes"][0]["primitives"][0];
  const json& pos_acc = g.doc["accessors"][prim["attributes"]["POSITION"].get<int>()];
  EXPECT_GT(pos_acc["count"].get<int>(), 24 * 8 - 1);
  EXPECT_EQ(pos_acc["min"].size(), 3u);
  const std::vector<float> w = g.Floats(prim["attributes"]["WEIGHTS_0"]);
  for (size_t v = 0; v < w.size(); v += 4) ASSERT_FLOAT_EQ(w[v] + w[v + 1] + w[v + 2] + w[v + 3], 1.0f);
  EXPECT_EQ(nodes.back()["skin"], 0);
  EXPECT_FALSE(g.doc.contains("extensionsUsed"));
  ExpectAnimationReproducesClip(g, clip);
}

TEST(GltfWriter, VrmaMapsTheHumanoidBones) {
  const MotionClip clip = testing::RandomDance(10, 2);
  absl::StatusOr<std::string> bytes = MotionToGltf(clip, GltfKind::kVrma);
  ASSERT_TRUE(bytes.ok()) << bytes.status();
  const Gltf g = ParseGlb(*bytes);
  EXPECT_EQ(g.doc["extensionsUsed"], json::array({"VRMC_vrm_animation"}));
  const json& ext = g.doc["extensions"]["VRMC_vrm_animation"];
  EXPECT_EQ(ext["specVersion"], "1.0");
  const json& bones = ext["humanoid"]["humanBones"];
  EXPECT_EQ(bones.size(), 22u);
  for (const HumanoidBone& b : kHumanoidBones) {
    ASSERT_TRUE(bones.contains(b.vrm_name)) << b.vrm_name;
    EXPECT_EQ(g.doc["nodes"][bones[b.vrm_name]["node"].get<int>()]["name"], b.smpl_name);
  }
  EXPECT_FALSE(g.doc.contains("meshes"));
  EXPECT_FALSE(g.doc.contains("skins"));
  ExpectAnimationReproducesClip(g, clip);
}

TEST(GltfWriter, TextGltfEmbedsTheSameBuffer) {
  const MotionClip clip = testing::RandomDance(5, 3);
  const Gltf glb = ParseGlb(*MotionToGltf(clip, GltfKind::kGlb));
  Gltf text;
  text.doc = json::parse(*MotionToGltf(clip, GltfKind::kGltf));
  const std::string uri = text.doc["buffers"][0]["uri"];
  const std::string prefix = "data:application/octet-stream;base64,";
  ASSERT_TRUE(absl::StartsWith(uri, prefix));
  ASSERT_TRUE(absl::Base64Unescape(uri.substr(prefix.size()), &text.bin));
  EXPECT_EQ(text.bin, glb.bin);
  ExpectAnimationReproducesClip(text, clip);
}

TEST(GltfWriter, KindFromExtensionAndErrors) {
  GltfKind k;
  EXPECT_TRUE(GltfKindForPath("a/b.GLB", &k));
  EXPECT_EQ(k, GltfKind::kGlb);
  EXPECT_TRUE(GltfKindForPath("x.vrma", &k));
  EXPECT_EQ(k, GltfKind::kVrma);
  EXPECT_TRUE(GltfKindForPath("x.gltf", &k));
  EXPECT_EQ(k, GltfKind::kGltf);
  EXPECT_FALSE(GltfKindForPath("x.json", &k));
  EXPECT_FALSE(WriteMotionFile("/tmp/x.fbx", testing::RandomDance(2, 1)).ok());
  EXPECT_FALSE(MotionToGltf(testing::SmplSkeleton(), GltfKind::kGlb).ok());  // no frames
  MotionClip bad = testing::RandomDance(2, 1);
  bad.parents[5] = 7;
  EXPECT_FALSE(MotionToGltf(bad, GltfKind::kGlb).ok());
  bad = testing::RandomDance(2, 1);
  bad.rotations.pop_back();
  EXPECT_FALSE(MotionToGltf(bad, GltfKind::kVrma).ok());
}

}  // namespace
}  // namespace dance::client
