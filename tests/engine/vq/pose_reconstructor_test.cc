// PoseReconstructor against the Python reference (training/data/representation.py, rotations.py), via
// tests/engine/vq/pose_fixture.json (written by make_pose_fixture.py).
#include "engine/vq/pose_reconstructor.h"

#include <fstream>

#include "gtest/gtest.h"
#include "nlohmann/json.hpp"

namespace dance::engine {
namespace {

nlohmann::json LoadFixture() {
  std::ifstream f("tests/engine/vq/pose_fixture.json");
  EXPECT_TRUE(f.good()) << "run from the source root";
  return nlohmann::json::parse(f);
}

TEST(PoseReconstructor, MatchesPythonReference) {
  const nlohmann::json fx = LoadFixture();
  absl::StatusOr<Skeleton> skel = Skeleton::FromMetadata(fx);
  ASSERT_TRUE(skel.ok()) << skel.status();
  PoseReconstructor rec(*skel);
  PoseState state;
  const size_t frames = fx["upper"].size();
  ASSERT_GT(frames, 10u);
  double worst_pos = 0.0, worst_rot = 0.0;
  for (size_t t = 0; t < frames; ++t) {
    std::vector<float> up = fx["upper"][t].get<std::vector<float>>();
    std::vector<float> low = fx["lower"][t].get<std::vector<float>>();
    std::array<Eigen::Vector3f, kNumJoints> pos;
    std::array<Eigen::Quaternionf, kNumJoints> q;
    rec.Reconstruct(up.data(), low.data(), state, &pos, &q);
    for (int j = 0; j < kNumJoints; ++j) {
      const auto& e = fx["positions"][t][j];
      const Eigen::Vector3f want(e[0].get<float>(), e[1].get<float>(), e[2].get<float>());
      worst_pos = std::max(worst_pos, static_cast<double>((pos[j] - want).norm()));
      const auto& r = fx["rotations"][t][j];
      const Eigen::Quaternionf want_q(r[0].get<float>(), r[1].get<float>(), r[2].get<float>(), r[3].get<float>());
      worst_rot = std::max(worst_rot, static_cast<double>(q[j].angularDistance(want_q)));
      EXPECT_GE(q[j].w(), 0.0f);
    }
  }
  EXPECT_LT(worst_pos, 2e-4) << "metres";
  EXPECT_LT(worst_rot, 1e-3) << "radians";
  EXPECT_EQ(state.frames, static_cast<int64_t>(frames));
}

TEST(PoseReconstructor, RotationsReproduceSingleChildBones) {
  const nlohmann::json fx = LoadFixture();
  absl::StatusOr<Skeleton> skel = Skeleton::FromMetadata(fx);
  ASSERT_TRUE(skel.ok());
  PoseReconstructor rec(*skel);
  PoseState state;
  std::vector<float> up = fx["upper"][5].get<std::vector<float>>();
  std::vector<float> low = fx["lower"][5].get<std::vector<float>>();
  std::array<Eigen::Vector3f, kNumJoints> pos;
  std::array<Eigen::Quaternionf, kNumJoints> q;
  rec.Reconstruct(up.data(), low.data(), state, &pos, &q);
  std::array<Eigen::Quaternionf, kNumJoints> g;
  for (int j = 0; j < kNumJoints; ++j) {
    const int p = skel->parents[j];
    g[j] = p < 0 ? q[j] : g[p] * q[j];
  }
  for (int j = 1; j < kNumJoints; ++j) {
    const int p = skel->parents[j];
    if (skel->children[p].size() != 1) continue;  // frame joints approximate their children
    const Eigen::Vector3f fk = g[p] * skel->offsets[j];
    EXPECT_LT((fk - (pos[j] - pos[p])).norm(), 1e-4f) << "joint " << j;
  }
}

TEST(PoseReconstructor, BoneProjectionGivesCanonicalLengths) {
  const nlohmann::json fx = LoadFixture();
  absl::StatusOr<Skeleton> skel = Skeleton::FromMetadata(fx);
  ASSERT_TRUE(skel.ok());
  PoseReconstructor rec(*skel);
  std::array<Eigen::Vector3f, kNumJoints> pos;
  for (int j = 0; j < kNumJoints; ++j) pos[j] = Eigen::Vector3f(0.1f * j, std::sin(j * 1.0f), 0.3f * (j % 3));
  rec.ProjectBoneLengths(pos);
  for (int j = 1; j < kNumJoints; ++j) {
    EXPECT_NEAR((pos[j] - pos[skel->parents[j]]).norm(), skel->bone_lengths[j], 1e-5f);
  }
}

TEST(Skeleton, RefusesMalformedMetadata) {
  nlohmann::json md = LoadFixture();
  md["skeleton"]["parents"][3] = 7;  // a parent after its child
  EXPECT_FALSE(Skeleton::FromMetadata(md).ok());
  md = nlohmann::json::object();
  EXPECT_FALSE(Skeleton::FromMetadata(md).ok());
}

}  // namespace
}  // namespace dance::engine
