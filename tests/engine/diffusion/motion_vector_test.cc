// The motion vector and the canonical frame (docs/diffusion.md section 2): inverses, contacts, invariance.
#include "engine/diffusion/motion_vector.h"

#include <cmath>
#include <random>
#include <vector>

#include "gtest/gtest.h"

namespace dance::engine {
namespace {

constexpr float kTolerance = 1e-5f;  // metres, float32 round trips through double rotations

// A random pose around a pelvis at about hip height (the facing is well defined for almost every draw).
JointPositions RandomPose(std::mt19937& gen) {
  std::uniform_real_distribution<float> u(-0.8f, 0.8f);
  JointPositions p;
  p[0] = Eigen::Vector3f(u(gen), 0.9f + 0.1f * u(gen), u(gen));
  for (int j = 1; j < kNumJoints; ++j) p[j] = p[0] + Eigen::Vector3f(u(gen), u(gen), u(gen));
  return p;
}

// p rotated by R_y(yaw) about the origin and moved by (dx, 0, dz).
JointPositions Move(const JointPositions& p, double yaw, float dx, float dz) {
  return FromFrame(p, CanonicalFrame{yaw, dx, dz});
}

float MaxDiff(const JointPositions& a, const JointPositions& b) {
  float m = 0.0f;
  for (int j = 0; j < kNumJoints; ++j) m = std::max(m, (a[j] - b[j]).cwiseAbs().maxCoeff());
  return m;
}

TEST(MotionVector, PositionsOfVectorInvertsPoseVector) {
  std::mt19937 gen(1);
  for (int i = 0; i < 20; ++i) {
    const JointPositions p = RandomPose(gen);
    const Eigen::VectorXf v = PoseVector(p);
    ASSERT_EQ(v.size(), kMotionDims);
    EXPECT_TRUE(v.segment<4>(kMotionContact).isZero());
    EXPECT_NEAR(std::hypot(v(kMotionHeading), v(kMotionHeading + 1)), 1.0f, 1e-6f);
    EXPECT_LE(MaxDiff(PositionsOfVector(v), p), kTolerance);
  }
}

TEST(MotionVector, HeadingPairNeedNotBeUnit) {
  std::mt19937 gen(2);
  const JointPositions p = RandomPose(gen);
  Eigen::VectorXf v = PoseVector(p);
  v.segment<2>(kMotionHeading) *= 3.5f;
  EXPECT_LE(MaxDiff(PositionsOfVector(v), p), kTolerance);
}

TEST(MotionVector, LocalJointsAreInTheFacingFrame) {
  // Rotating and moving a pose changes only the pelvis and the heading, not the local joints.
  std::mt19937 gen(3);
  const JointPositions p = RandomPose(gen);
  const Eigen::VectorXf a = PoseVector(p), b = PoseVector(Move(p, 1.1, 2.0f, -3.0f));
  EXPECT_TRUE(a.segment(kMotionLocal, 69).isApprox(b.segment(kMotionLocal, 69), 1e-5f));
  EXPECT_FALSE(a.segment<2>(kMotionHeading).isApprox(b.segment<2>(kMotionHeading), 1e-3f));
}

TEST(CanonicalFrame, FirstFrameFacesPlusZAboveTheOrigin) {
  std::mt19937 gen(4);
  const JointPositions p = RandomPose(gen);
  const JointPositions local = ToFrame(p, FrameOf(p));
  EXPECT_NEAR(local[0].x(), 0.0f, 1e-6f);
  EXPECT_NEAR(local[0].z(), 0.0f, 1e-6f);
  EXPECT_FLOAT_EQ(local[0].y(), p[0].y());  // the height is kept
  EXPECT_NEAR(FacingYaw(local), 0.0, 1e-5);
  EXPECT_LE(MaxDiff(FromFrame(local, FrameOf(p)), p), kTolerance);
}

TEST(CanonicalFrame, WindowIsInvariantToTheWorldsYawAndTranslation) {
  std::mt19937 gen(5);
  std::vector<JointPositions> world, moved;
  for (int n = 0; n < 6; ++n) {
    world.push_back(RandomPose(gen));
    moved.push_back(Move(world.back(), -2.3, -1.5f, 4.0f));
  }
  const std::vector<JointPositions> a = ToFrame(world, FrameOf(world[0]));
  const std::vector<JointPositions> b = ToFrame(moved, FrameOf(moved[0]));
  for (int n = 0; n < 6; ++n) EXPECT_LE(MaxDiff(a[n], b[n]), kTolerance) << n;
}

TEST(MotionVector, ContactsFromFootSpeedsLastFrameRepeats) {
  std::mt19937 gen(6);
  const JointPositions rest = RandomPose(gen);
  // Frames 0-2 drift 5 mm per frame (0.15 m/s: contact); frame 3 is 2 cm further (0.6 m/s: none).
  std::vector<JointPositions> frames;
  for (int n = 0; n < 3; ++n) frames.push_back(Move(rest, 0.0, 0.005f * n, 0.0f));
  frames.push_back(Move(rest, 0.0, 0.01f + 0.02f, 0.0f));
  const Eigen::MatrixXf v = MotionVectors(frames);
  ASSERT_EQ(v.rows(), kMotionDims);
  ASSERT_EQ(v.cols(), 4);
  for (int i = 0; i < 4; ++i) {
    EXPECT_EQ(v(kMotionContact + i, 0), 1.0f);
    EXPECT_EQ(v(kMotionContact + i, 1), 1.0f);
    EXPECT_EQ(v(kMotionContact + i, 2), 0.0f);
    EXPECT_EQ(v(kMotionContact + i, 3), 0.0f);  // repeats frame 2
  }
  for (int n = 0; n < 4; ++n) {
    EXPECT_TRUE(v.col(n).head(kMotionContact).isApprox(PoseVector(frames[n]).head(kMotionContact))) << n;
  }
  // A lone frame has no neighbour: no contacts.
  EXPECT_TRUE(MotionVectors({rest}).col(0).segment<4>(kMotionContact).isZero());
}

TEST(MotionVector, ContactsAreOfTheAnklesAndFeet) {
  std::mt19937 gen(7);
  const JointPositions rest = RandomPose(gen);
  JointPositions next = rest;
  next[8] += Eigen::Vector3f(0.1f, 0.0f, 0.0f);  // the right ankle moves 3 m/s, nothing else
  const Eigen::MatrixXf v = MotionVectors({rest, next});
  EXPECT_EQ(v(kMotionContact + 0, 0), 1.0f);
  EXPECT_EQ(v(kMotionContact + 1, 0), 0.0f);
  EXPECT_EQ(v(kMotionContact + 2, 0), 1.0f);
  EXPECT_EQ(v(kMotionContact + 3, 0), 1.0f);
}

}  // namespace
}  // namespace dance::engine
