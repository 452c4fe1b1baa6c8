// PoseEncoder: the pose features are the exact inverse of PoseReconstructor's root integration, and the
// shipped model's VQ encoder gives back the codes a dance was decoded from (the VQ-VAE round trip).
#include "engine/vq/pose_encoder.h"

#include <random>
#include <vector>

#include "engine/runtime/model.h"
#include "engine/vq/pose_reconstructor.h"
#include "gtest/gtest.h"

namespace dance::engine {
namespace {

// Decodes `codes` (upper, lower per step) from fresh decoder states into global positions.
std::vector<JointPositions> DecodeCodes(const Model& model, const std::vector<std::pair<int, int>>& codes) {
  VqDecoderState us = model.upper_decoder().NewState(), ls = model.lower_decoder().NewState();
  VqDecoderScratch usc = model.upper_decoder().NewScratch(), lsc = model.lower_decoder().NewScratch();
  PoseReconstructor rec(model.skeleton());
  PoseState root;
  std::vector<JointPositions> out;
  for (const auto& [u, l] : codes) {
    const Eigen::MatrixXf up = model.upper_decoder().Decode(u, us, usc);
    const Eigen::MatrixXf low = model.lower_decoder().Decode(l, ls, lsc);
    for (int f = 0; f < up.cols(); ++f) {
      JointPositions& p = out.emplace_back();
      rec.Reconstruct(up.col(f).data(), low.col(f).data(), root, &p, nullptr);
    }
  }
  return out;
}

TEST(PoseEncoder, FeaturesInvertTheRootIntegration) {
  absl::StatusOr<std::shared_ptr<const Model>> model = LoadModel("models/default.dncw");
  ASSERT_TRUE(model.ok()) << model.status() << " (run from the source root)";
  // A decoded dance that walks and turns: random codes.
  std::mt19937 gen(3);
  std::vector<std::pair<int, int>> codes;
  for (int i = 0; i < 40; ++i) codes.emplace_back(gen() % 512, gen() % 512);
  const std::vector<JointPositions> dance = DecodeCodes(**model, codes);
  const PoseFeatures f = EncodePoseFeatures(dance);
  ASSERT_EQ(f.upper.cols(), static_cast<Eigen::Index>(dance.size()));
  PoseReconstructor rec((*model)->skeleton());
  PoseState root{.yaw = f.yaw[0], .root_x = f.root_xz[0].x(), .root_z = f.root_xz[0].y()};
  // Frame 0 has zero velocity and yaw rate: reconstructing from frame 0's yaw and root gives every frame.
  double worst = 0.0;
  for (size_t n = 0; n < dance.size(); ++n) {
    JointPositions p;
    rec.Reconstruct(f.upper.col(n).data(), f.lower.col(n).data(), root, &p, nullptr);
    for (int j = 0; j < kNumJoints; ++j) worst = std::max(worst, static_cast<double>((p[j] - dance[n][j]).norm()));
  }
  EXPECT_LT(worst, 2e-4) << "metres";
  // The yaw moved (the check covers turning, not just a fixed facing).
  EXPECT_GT(std::abs(f.yaw.back() - f.yaw.front()) + std::abs(f.root_xz.back().x() - f.root_xz.front().x()), 0.05);
}

TEST(PoseEncoder, ShippedEncoderRecoversTheCodesOfADecodedDance) {
  absl::StatusOr<std::shared_ptr<const Model>> model = LoadModel("models/default.dncw");
  ASSERT_TRUE(model.ok()) << model.status();
  const Model& m = **model;
  ASSERT_NE(m.upper_encoder(), nullptr);
  ASSERT_NE(m.lower_encoder(), nullptr);
  EXPECT_EQ(m.upper_encoder()->downsample(), 4);
  // A code sequence shaped like a dance (codes held for a few steps, then changed).
  std::vector<std::pair<int, int>> codes;
  std::mt19937 gen(11);
  int u = 7, l = 9;
  for (int i = 0; i < 120; ++i) {
    if (gen() % 3 == 0) u = gen() % 512;
    if (gen() % 3 == 0) l = gen() % 512;
    codes.emplace_back(u, l);
  }
  const std::vector<JointPositions> dance = DecodeCodes(m, codes);
  const PoseFeatures f = EncodePoseFeatures(dance);
  const std::vector<int> up = m.upper_encoder()->Encode(f.upper);
  const std::vector<int> low = m.lower_encoder()->Encode(f.lower);
  ASSERT_EQ(up.size(), codes.size());
  ASSERT_EQ(low.size(), codes.size());
  // Nearby codes decode to nearly the same motion, so compare by what they decode to as well as by index:
  // the re-encoded dance decodes back close to the dance (the round trip of the VQ-VAE).
  std::vector<std::pair<int, int>> again;
  int same_u = 0, same_l = 0;
  for (size_t i = 0; i < codes.size(); ++i) {
    same_u += up[i] == codes[i].first;
    same_l += low[i] == codes[i].second;
    again.emplace_back(up[i], low[i]);
  }
  // Compared in the facing frame (the upper features), so a heading that drifted apart does not count.
  const PoseFeatures g = EncodePoseFeatures(DecodeCodes(m, again));
  const Eigen::VectorXf mean = f.upper.rowwise().mean();
  const double err = (g.upper - f.upper).cwiseAbs().mean();
  const double spread = (f.upper.colwise() - mean).cwiseAbs().mean();
  RecordProperty("same_upper", same_u);
  RecordProperty("same_lower", same_l);
  std::printf("round trip: %d / %zu upper and %d / %zu lower codes recovered; upper pose error %.4f m against the motion's spread %.4f m\n",
              same_u, codes.size(), same_l, codes.size(), err, spread);
  // Chance is 1 in 512; a broken featuriser or encoder recovers nothing.
  EXPECT_GT(same_u, static_cast<int>(codes.size()) / 4);
  EXPECT_GT(same_l, static_cast<int>(codes.size()) / 4);
  EXPECT_LT(err, 0.5 * spread);
}

TEST(PoseEncoder, TinyTestModelHasItsEncodersToo) {
  absl::StatusOr<std::shared_ptr<const Model>> model = LoadModel("models/test-tiny.dncw");
  ASSERT_TRUE(model.ok()) << model.status();
  // The tiny model is exported with its encoders too (training/fixtures.py uses export's vq_tensors).
  EXPECT_NE((*model)->upper_encoder(), nullptr);
}

}  // namespace
}  // namespace dance::engine
