// GenerateSgmdDance on the tiny SGMD model (random weights, 8-frame windows sharing 4): the seam blend
// continues the motion at every window seam and into and out of given frames, and never moves a given joint.
#include "engine/diffusion/sgmd_dance.h"

#include <memory>
#include <random>
#include <vector>

#include "Eigen/Geometry"
#include "gtest/gtest.h"

namespace dance::engine {
namespace {

constexpr char kTiny[] = "models/sgmd-tiny.dncw";

std::shared_ptr<const SgmdModel> Tiny() {
  absl::StatusOr<std::shared_ptr<const SgmdModel>> m = SgmdModel::Load(kTiny);
  EXPECT_TRUE(m.ok()) << m.status() << " (run from the source root)";
  return m.ok() ? *m : nullptr;
}

// Song features of `frames` frames: random but fixed.
audio::FeatureFrames Song(const SgmdModel& model, int64_t frames) {
  audio::FeatureFrames f;
  std::mt19937 gen(5);
  std::normal_distribution<float> normal(0.0f, 1.0f);
  f.features.resize(static_cast<size_t>(frames * model.config().feature_dim));
  f.pre.resize(static_cast<size_t>(frames * model.config().pre_dim));
  for (float& v : f.features) v = normal(gen);
  for (float& v : f.pre) v = normal(gen);
  return f;
}

// How far joint j of frame m is from the constant-velocity continuation of frames m - 2 and m - 1.
float Kink(const std::vector<PoseFrame>& frames, int64_t m, int j) {
  const Eigen::Vector3f want = 2.0f * frames[m - 1].positions[j] - frames[m - 2].positions[j];
  return (frames[m].positions[j] - want).norm();
}

SgmdDanceOptions Options(int blend) {
  SgmdDanceOptions o;
  o.steps = 3;
  o.foot_lock = false;  // the blend alone (the foot lock moves the legs afterwards)
  o.seam_blend_frames = blend;
  return o;
}

TEST(SgmdDance, SeamBlendContinuesThePelvisAtEveryWindowSeam) {
  std::shared_ptr<const SgmdModel> model = Tiny();
  ASSERT_NE(model, nullptr);
  const audio::FeatureFrames song = Song(*model, 40);
  absl::StatusOr<SgmdDance> raw = GenerateSgmdDance(*model, song, Options(0));
  absl::StatusOr<SgmdDance> blended = GenerateSgmdDance(*model, song, Options(3));
  ASSERT_TRUE(raw.ok()) << raw.status();
  ASSERT_TRUE(blended.ok()) << blended.status();
  ASSERT_EQ(raw->overlap_frames, 4);
  ASSERT_EQ(blended->frames.size(), 40u);
  // Windows start every 4 frames, so frames 8, 12, ... are each window's first new frame.
  float raw_worst = 0.0f;
  for (int64_t m = 8; m < 40; m += 4) {
    raw_worst = std::max(raw_worst, Kink(raw->frames, m, 0));
    EXPECT_LE(Kink(blended->frames, m, 0), 1e-4f) << "seam at frame " << m;
  }
  EXPECT_GT(raw_worst, 1e-2f) << "the unblended seams already continue: the test shows nothing";
  // The first window is untouched: nothing before it to meet.
  for (int64_t m = 0; m < 8; ++m) {
    EXPECT_EQ(blended->frames[m].positions[0], raw->frames[m].positions[0]) << "frame " << m;
  }
}

TEST(SgmdDance, SeamBlendMeetsGivenFramesAndNeverMovesThem) {
  std::shared_ptr<const SgmdModel> model = Tiny();
  ASSERT_NE(model, nullptr);
  const audio::FeatureFrames song = Song(*model, 40);
  // Frames 17..22 given whole (a span to keep, as inpainting's known part).
  std::vector<JointPositions> span(6);
  for (size_t i = 0; i < span.size(); ++i) {
    for (int j = 0; j < kNumJoints; ++j) span[i][j] = Eigen::Vector3f(0.1f * i, 0.9f + 0.01f * j, -0.05f * j);
  }
  SgmdDanceOptions o = Options(4);
  o.controls.motion = SeedTrack(span, 17);
  absl::StatusOr<SgmdDance> d = GenerateSgmdDance(*model, song, o);
  ASSERT_TRUE(d.ok()) << d.status();
  for (size_t i = 0; i < span.size(); ++i) {
    for (int j = 0; j < kNumJoints; ++j) {
      ASSERT_LE((d->frames[17 + i].positions[j] - span[i][j]).norm(), 1e-5f) << "frame " << 17 + i << " joint " << j;
    }
  }
  // Into the span: frame 16 continues backwards from 18 and 17; out of it: frame 23 continues 21 and 22.
  const Eigen::Vector3f into = 2.0f * d->frames[17].positions[0] - d->frames[18].positions[0];
  EXPECT_LE((d->frames[16].positions[0] - into).norm(), 1e-4f);
  EXPECT_LE(Kink(d->frames, 23, 0), 1e-4f);
}

// A dancer walking along +X at 1 m/s, facing +Z, for `frames` frames.
std::vector<JointPositions> Walk(int frames) {
  std::vector<JointPositions> w(static_cast<size_t>(frames));
  for (int m = 0; m < frames; ++m) {
    for (int j = 0; j < kNumJoints; ++j) w[m][j] = Eigen::Vector3f(m / 30.0f, 0.9f + 0.02f * j, 0.0f);
    // Hips and shoulders across X, so the body faces along Z; the hands ahead of it.
    w[m][1].x() += 0.1f;
    w[m][2].x() -= 0.1f;
    w[m][16].x() += 0.2f;
    w[m][17].x() -= 0.2f;
    w[m][22].z() += 0.3f;
    w[m][23].z() += 0.3f;
  }
  return w;
}

TEST(SgmdDance, GlitchRepairReplacesShortJumpsAwayAndKeepsGivenAndLongOnes) {
  std::vector<JointPositions> w = Walk(60);
  const std::vector<JointPositions> clean = w;
  auto teleport = [&](int from, int to) {  // frames [from, to) jump 3 m aside
    for (int m = from; m < to; ++m) {
      for (Eigen::Vector3f& q : w[m]) q += Eigen::Vector3f(0.0f, 0.0f, 3.0f);
    }
  };
  teleport(10, 12);   // 2 frames: a glitch
  for (int m = 30; m < 32; ++m) {  // 2 frames turned about the pelvis by 180 degrees: a glitch
    for (Eigen::Vector3f& q : w[m]) q = Eigen::Vector3f(2.0f * w[m][0].x() - q.x(), q.y(), -q.z());
  }
  teleport(40, 60);   // 20 frames: longer than 6, a move of its own, kept
  Controls none;
  // The 4 glitch frames, and perhaps the one at the long move's start (the median there is half and half).
  const int64_t repaired = sgmd_internal::RepairGlitches(none, 6, w, 60);
  EXPECT_GE(repaired, 4);
  EXPECT_LE(repaired, 5);
  for (int m : {9, 10, 11, 12, 29, 30, 31, 32}) {
    for (int j = 0; j < kNumJoints; ++j) {
      ASSERT_LE((w[m][j] - clean[m][j]).norm(), 1e-4f) << "frame " << m << " joint " << j;  // the walk, interpolated
    }
  }
  for (int m = 41; m < 60; ++m) EXPECT_NEAR(w[m][0].z(), 3.0f, 1e-5f) << "frame " << m;
  // A given pelvis is never touched, glitch or not.
  std::vector<JointPositions> g = clean;
  for (int m = 20; m < 22; ++m) {
    for (Eigen::Vector3f& q : g[m]) q += Eigen::Vector3f(0.0f, 0.0f, 3.0f);
  }
  Controls given;
  given.motion = SeedTrack(std::vector<JointPositions>(g.begin() + 20, g.begin() + 22), 20);
  EXPECT_EQ(sgmd_internal::RepairGlitches(given, 6, g, 60), 0);
  EXPECT_NEAR(g[20][0].z(), 3.0f, 1e-5f);
  // 0 = off.
  std::vector<JointPositions> off = clean;
  for (Eigen::Vector3f& q : off[30]) q += Eigen::Vector3f(0.0f, 0.0f, 3.0f);
  EXPECT_EQ(sgmd_internal::RepairGlitches(none, 0, off, 60), 0);
}

TEST(SgmdDance, ReanchoringPutsAWindowThatJumpedBackOnTheWayItWasGoing) {
  const std::vector<JointPositions> clean = Walk(60);
  std::vector<JointPositions> w = clean;
  // From frame 22 (two frames after a window seam at 20) the dance jumps 2 m aside, turned by 90 degrees.
  const Eigen::Matrix3f r = Eigen::AngleAxisf(1.5707963f, Eigen::Vector3f::UnitY()).toRotationMatrix();
  const Eigen::Vector3f pivot = clean[22][0];
  for (int m = 22; m < 60; ++m) {
    for (Eigen::Vector3f& q : w[m]) q = r * (q - pivot) + pivot + Eigen::Vector3f(0.0f, 0.0f, 2.0f);
  }
  Controls none;
  EXPECT_EQ(sgmd_internal::ReanchorSeams(none, {20}, 8, w, 60), 1);
  for (int m = 0; m < 60; ++m) {
    for (int j = 0; j < kNumJoints; ++j) {
      ASSERT_LE((w[m][j] - clean[m][j]).norm(), 1e-3f) << "frame " << m << " joint " << j;
    }
  }
  // A smooth seam is left alone, and so is a given pelvis after a break (the dance moves up to it only).
  EXPECT_EQ(sgmd_internal::ReanchorSeams(none, {20}, 8, w, 60), 0);
  std::vector<JointPositions> g = clean;
  for (int m = 22; m < 60; ++m) {
    for (Eigen::Vector3f& q : g[m]) q += Eigen::Vector3f(0.0f, 0.0f, 2.0f);
  }
  Controls given;
  given.motion = SeedTrack(std::vector<JointPositions>(g.begin() + 40, g.begin() + 44), 40);
  EXPECT_EQ(sgmd_internal::ReanchorSeams(given, {20}, 8, g, 60), 1);
  EXPECT_LE((g[30][0] - clean[30][0]).norm(), 1e-3f);
  EXPECT_NEAR(g[40][0].z(), 2.0f, 1e-5f);
}

TEST(SgmdDance, NegativeSeamBlendIsRefused) {
  std::shared_ptr<const SgmdModel> model = Tiny();
  ASSERT_NE(model, nullptr);
  absl::StatusOr<SgmdDance> d = GenerateSgmdDance(*model, Song(*model, 16), Options(-1));
  EXPECT_EQ(d.status().code(), absl::StatusCode::kInvalidArgument) << d.status();
}

}  // namespace
}  // namespace dance::engine
