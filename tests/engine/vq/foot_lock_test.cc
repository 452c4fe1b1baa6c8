// FootLock: planted feet held by leg IK, free feet untouched, bone lengths exact, the correction released.
#include "engine/vq/foot_lock.h"

#include <fstream>

#include "engine/vq/pose_reconstructor.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"

namespace dance::engine {
namespace {

using Pose = std::array<Eigen::Vector3f, kNumJoints>;
constexpr int kLeftHip = 1, kLeftKnee = 4, kLeftAnkle = 7, kLeftFoot = 10, kRightFoot = 11;

Skeleton LoadSkeleton() {
  std::ifstream f("tests/engine/vq/pose_fixture.json");
  EXPECT_TRUE(f.good()) << "run from the source root";
  absl::StatusOr<Skeleton> skel = Skeleton::FromMetadata(nlohmann::json::parse(f));
  EXPECT_TRUE(skel.ok()) << skel.status();
  return *skel;
}

// The rest pose (straight legs), standing with its lower foot joint `floor` metres above the floor.
Pose Standing(const Skeleton& skel, float floor) {
  Pose p;
  p[0].setZero();
  for (int j = 1; j < kNumJoints; ++j) p[j] = p[skel.parents[j]] + skel.offsets[j];
  const float lowest = std::min(p[kLeftFoot].y(), p[kRightFoot].y());
  for (Eigen::Vector3f& v : p) v.y() += floor - lowest;
  return p;
}

// The standing pose with its left knee and ankle at `knee` and `ankle` (the foot carried with the ankle),
// lifted so its left foot joint is `floor` metres up.
Pose WithLeftLeg(const Skeleton& skel, const Eigen::Vector3f& knee, const Eigen::Vector3f& ankle, float floor) {
  Pose p = Standing(skel, 0.0f);
  p[kLeftFoot] += ankle - p[kLeftAnkle];
  p[kLeftKnee] = knee;
  p[kLeftAnkle] = ankle;
  const float left = p[kLeftFoot].y();
  for (Eigen::Vector3f& v : p) v.y() += floor - left;
  return p;
}

// A standing pose with its left leg bent: the thigh turned `thigh` radians and the shin `shin` radians
// about the X axis from their rest directions (positive turns swing the lower end back, to -Z; the body
// faces +Z).
Pose LeftLeg(const Skeleton& skel, float thigh, float shin, float floor) {
  const Pose rest = Standing(skel, 0.0f);
  const Eigen::AngleAxisf rt(thigh, Eigen::Vector3f::UnitX()), rs(shin, Eigen::Vector3f::UnitX());
  const Eigen::Vector3f knee = rest[kLeftHip] + rt * (rest[kLeftKnee] - rest[kLeftHip]);
  const Eigen::Vector3f ankle = knee + rs * (rest[kLeftAnkle] - rest[kLeftKnee]);
  return WithLeftLeg(skel, knee, ankle, floor);
}

// The same with absolute bone directions: the thigh and the shin `thigh` and `shin` radians from hanging
// straight down (positive: lower end back, -Z); equal angles put hip, knee and ankle exactly in line.
Pose LeftLegInLine(const Skeleton& skel, float thigh, float shin, float floor) {
  const Pose rest = Standing(skel, 0.0f);
  const Eigen::Vector3f knee =
      rest[kLeftHip] + skel.bone_lengths[kLeftKnee] * Eigen::Vector3f(0.0f, -std::cos(thigh), -std::sin(thigh));
  const Eigen::Vector3f ankle =
      knee + skel.bone_lengths[kLeftAnkle] * Eigen::Vector3f(0.0f, -std::cos(shin), -std::sin(shin));
  return WithLeftLeg(skel, knee, ankle, floor);
}

Pose Translated(Pose p, const Eigen::Vector3f& d) {
  for (Eigen::Vector3f& v : p) v += d;
  return p;
}

float Horizontal(const Eigen::Vector3f& a, const Eigen::Vector3f& b) {
  return Eigen::Vector2f(a.x() - b.x(), a.z() - b.z()).norm();
}

void ExpectCanonicalBones(const Skeleton& skel, const Pose& p, int frame) {
  for (int j = 1; j < kNumJoints; ++j) {
    EXPECT_NEAR((p[j] - p[skel.parents[j]]).norm(), skel.bone_lengths[j], 1e-4f) << "joint " << j << " frame "
                                                                                  << frame;
  }
}

TEST(FootLock, ContactWeightRampsWithHeightAndSpeed) {
  EXPECT_FLOAT_EQ(FootLock::ContactWeight(0.0f, 0.0f), 1.0f);
  EXPECT_FLOAT_EQ(FootLock::ContactWeight(kFootLockHeightFull, kFootLockSpeedFull), 1.0f);
  EXPECT_FLOAT_EQ(FootLock::ContactWeight(kFootLockHeightNone, 0.0f), 0.0f);
  EXPECT_FLOAT_EQ(FootLock::ContactWeight(0.0f, kFootLockSpeedNone), 0.0f);
  EXPECT_FLOAT_EQ(FootLock::ContactWeight(0.5f, 5.0f), 0.0f);
  const float mid_h = 0.5f * (kFootLockHeightFull + kFootLockHeightNone);
  const float mid_v = 0.5f * (kFootLockSpeedFull + kFootLockSpeedNone);
  EXPECT_NEAR(FootLock::ContactWeight(mid_h, 0.0f), 0.5f, 1e-5f);
  EXPECT_NEAR(FootLock::ContactWeight(mid_h, mid_v), 0.25f, 1e-5f);
}

// The body drifts back at 0.1 m/s over a left foot on the floor behind the hip (a decoded stance foot that
// skates): the lock holds the foot where it was planted and bends the knee (forward) to reach it, and
// leaves the hips and the upper body where the decoder put them.
void ExpectDriftHeld(const Pose& base) {
  const Skeleton skel = LoadSkeleton();
  const FootLock lock(skel);
  FootLockState state;
  const Eigen::Vector3f velocity(0.0f, 0.0f, -0.1f / 30.0f);  // per frame
  Eigen::Vector3f planted;
  for (int t = 0; t < 30; ++t) {
    const Pose raw = Translated(base, velocity * static_cast<float>(t));
    Pose out = raw;
    lock.Apply(state, &out);
    if (t == 0) planted = out[kLeftFoot];
    ExpectCanonicalBones(skel, out, t);
    for (int j : {0, 1, 2, 3, 6, 9, 12, 15, 16, 17, 20, 21}) EXPECT_EQ(out[j], raw[j]) << "joint " << j;
    EXPECT_LT(Horizontal(out[kLeftFoot], planted), 1e-4f) << "frame " << t;
    EXPECT_NEAR(out[kLeftFoot].y(), raw[kLeftFoot].y(), 1e-6f);  // heights are the decoder's
    if (t == 29) {
      EXPECT_GT(Horizontal(raw[kLeftFoot], planted), 0.09f);  // the raw foot skated ~10 cm
      EXPECT_GT(out[kLeftKnee].z(), out[kLeftHip].z() + 0.03f);  // the knee bent forward
    }
  }
}

TEST(FootLock, HoldsADriftingPlantedFootBentLeg) {
  const Skeleton skel = LoadSkeleton();
  ExpectDriftHeld(LeftLeg(skel, -0.05f, 0.25f, 0.01f));
}

// One frame of the lock on decoded pose `raw` whose left foot is already held with a correction that
// brings the ankle under the hip (at most kFootLockMaxShift away).
Pose HoldUnderTheHip(const Skeleton& skel, const Pose& raw) {
  const FootLock lock(skel);
  FootLockState state;
  FootLockState::Foot& foot = state.feet[0];
  foot.correction = Eigen::Vector2f(raw[kLeftHip].x() - raw[kLeftAnkle].x(), raw[kLeftHip].z() - raw[kLeftAnkle].z());
  EXPECT_LT(foot.correction.norm(), kFootLockMaxShift);
  foot.previous = Eigen::Vector2f(0.5f * (raw[kLeftAnkle].x() + raw[kLeftFoot].x()),
                                  0.5f * (raw[kLeftAnkle].z() + raw[kLeftFoot].z()));
  foot.has_previous = true;
  Pose out = raw;
  lock.Apply(state, &out);
  return out;
}

TEST(FootLock, AStraightDecodedLegBendsItsKneeForward) {
  // Hip, knee and ankle in line, the ankle 0.15 rad behind the hip: a straight leg has no bend of its own,
  // and the held ankle (toward under the hip) needs one: the knee bends forward (+Z).
  const Skeleton skel = LoadSkeleton();
  const Pose raw = LeftLegInLine(skel, 0.15f, 0.15f, 0.01f);
  const Pose out = HoldUnderTheHip(skel, raw);
  ExpectCanonicalBones(skel, out, 0);
  EXPECT_GT(Horizontal(out[kLeftAnkle], raw[kLeftAnkle]), 0.05f);  // held toward under the hip
  EXPECT_GT(out[kLeftKnee].z(), out[kLeftHip].z() + 0.03f);
}

TEST(FootLock, NeverBendsAKneeBackwards) {
  // The decoded knee behind its hip-ankle line (thigh turned back, shin less): the held leg still bends
  // forward, not into a reversed knee.
  const Skeleton skel = LoadSkeleton();
  const Pose raw = LeftLeg(skel, 0.25f, 0.05f, 0.01f);
  const Eigen::Vector3f axis = (raw[kLeftAnkle] - raw[kLeftHip]).normalized();
  const Eigen::Vector3f knee = raw[kLeftKnee] - raw[kLeftHip];
  ASSERT_LT((knee - knee.dot(axis) * axis).z(), -0.01f) << "the decoded knee is behind its line";
  const Pose out = HoldUnderTheHip(skel, raw);
  ExpectCanonicalBones(skel, out, 0);
  EXPECT_GT(Horizontal(out[kLeftAnkle], raw[kLeftAnkle]), 0.05f);
  const Eigen::Vector3f held_axis = (out[kLeftAnkle] - out[kLeftHip]).normalized();
  const Eigen::Vector3f held_knee = out[kLeftKnee] - out[kLeftHip];
  EXPECT_GT((held_knee - held_knee.dot(held_axis) * held_axis).z(), 0.01f) << "the knee in front of its line";
}

TEST(FootLock, LetsGoGraduallyAsTheLegStraightens) {
  // The body drifts forward over a bent leg's planted foot (held ~10 cm behind where it was decoded); then
  // the decoded leg straightens over half a second until hip, knee and ankle are exactly in line, so the
  // held foot could not be reached at the end. The correction shrinks a little every frame, never cut at once.
  const Skeleton skel = LoadSkeleton();
  const FootLock lock(skel);
  FootLockState state;
  const Pose bent = LeftLegInLine(skel, -0.3f, 0.5f, 0.01f);
  for (int t = 0; t < 30; ++t) {
    Pose p = Translated(bent, Eigen::Vector3f(0.0f, 0.0f, 0.1f / 30.0f * static_cast<float>(t)));
    lock.Apply(state, &p);
  }
  ASSERT_GT(state.feet[0].correction.norm(), 0.08f);
  const Eigen::Vector3f at = Eigen::Vector3f(0.0f, 0.0f, 0.1f / 30.0f * 29.0f);
  Pose previous;
  float worst = 0.0f;
  for (int t = 0; t <= 30; ++t) {
    const float k = std::max(1.0f - static_cast<float>(t) / 15.0f, 0.0f);  // in line from frame 15 on
    const Pose raw = Translated(LeftLegInLine(skel, 0.1f - 0.4f * k, 0.1f + 0.4f * k, 0.01f), at);
    Pose out = raw;
    lock.Apply(state, &out);
    ExpectCanonicalBones(skel, out, t);
    if (t > 0) worst = std::max(worst, (out[kLeftFoot] - previous[kLeftFoot]).norm());
    previous = out;
  }
  EXPECT_LT(worst, 0.02f) << "metres per frame";  // the release rate: kFootLockRelease x ~10 cm
  EXPECT_LT(state.feet[0].correction.norm(), 0.01f);
}

TEST(FootLock, HoldsTheFootBehindAStraightLeg) {
  // Hip, knee and ankle in line, the body drifting back over a planted foot behind it: holding it shortens the
  // hip-ankle distance (the knee bends), so a straight leg is held like a bent one.
  const Skeleton skel = LoadSkeleton();
  const FootLock lock(skel);
  FootLockState state;
  const Pose base = LeftLegInLine(skel, 0.1f, 0.1f, 0.01f);
  Eigen::Vector3f planted;
  for (int t = 0; t < 20; ++t) {
    const Pose raw = Translated(base, Eigen::Vector3f(0.0f, 0.0f, -0.1f / 30.0f * static_cast<float>(t)));
    Pose out = raw;
    lock.Apply(state, &out);
    if (t == 0) planted = out[kLeftFoot];
    ExpectCanonicalBones(skel, out, t);
    EXPECT_LT(Horizontal(out[kLeftFoot], planted), 1e-3f) << "frame " << t;
  }
}

TEST(FootLock, LeavesAFastOrLiftedFootAlone) {
  const Skeleton skel = LoadSkeleton();
  const FootLock lock(skel);
  // On the floor but sliding at 2 m/s.
  FootLockState fast;
  const Pose base = Standing(skel, 0.0f);
  for (int t = 0; t < 20; ++t) {
    const Pose raw = Translated(base, Eigen::Vector3f(2.0f / 30.0f * static_cast<float>(t), 0.0f, 0.0f));
    Pose out = raw;
    lock.Apply(fast, &out);
    for (int j = 0; j < kNumJoints; ++j) EXPECT_EQ(out[j], raw[j]) << "joint " << j << " frame " << t;
  }
  // Slow, but 20 cm up.
  FootLockState lifted;
  const Pose up = Standing(skel, 0.2f);
  for (int t = 0; t < 20; ++t) {
    const Pose raw = Translated(up, Eigen::Vector3f(0.0f, 0.0f, 0.05f / 30.0f * static_cast<float>(t)));
    Pose out = raw;
    lock.Apply(lifted, &out);
    for (int j = 0; j < kNumJoints; ++j) EXPECT_EQ(out[j], raw[j]) << "joint " << j << " frame " << t;
  }
}

TEST(FootLock, ReleasesTheFootWhenItLifts) {
  const Skeleton skel = LoadSkeleton();
  const FootLock lock(skel);
  FootLockState state;
  const Pose base = LeftLeg(skel, -0.05f, 0.25f, 0.01f);
  Pose raw;
  for (int t = 0; t < 30; ++t) {  // planted and drifting: a correction builds up
    raw = Translated(base, Eigen::Vector3f(0.0f, 0.0f, -0.1f / 30.0f * static_cast<float>(t)));
    lock.Apply(state, &raw);
  }
  const float held = state.feet[0].correction.norm();
  EXPECT_GT(held, 0.08f);
  // The body stops and the feet lift 15 cm: the correction fades, a little every frame, never jumping.
  const Pose lifted = Translated(base, Eigen::Vector3f(0.0f, 0.15f, -29.0f * 0.1f / 30.0f));
  Pose previous;
  for (int t = 0; t < 60; ++t) {
    Pose out = lifted;
    lock.Apply(state, &out);
    ExpectCanonicalBones(skel, out, t);
    if (t > 0) {
      EXPECT_LT((out[kLeftFoot] - previous[kLeftFoot]).norm(), kFootLockRelease * held + 1e-4f);
    }
    previous = out;
  }
  EXPECT_LT(state.feet[0].correction.norm(), 1e-3f);
  Pose out = lifted;
  lock.Apply(state, &out);
  EXPECT_LT((out[kLeftFoot] - lifted[kLeftFoot]).norm(), 1e-3f);
}

TEST(FootLock, NeverStretchesTheLegPastItsReach) {
  // The hips rise and drift away from a planted foot faster than it can follow: the correction is cut to
  // what the leg can reach, and the bones keep their lengths.
  const Skeleton skel = LoadSkeleton();
  const FootLock lock(skel);
  FootLockState state;
  const Pose base = Standing(skel, 0.0f);
  const float reach = skel.bone_lengths[kLeftKnee] + skel.bone_lengths[kLeftAnkle];
  for (int t = 0; t < 40; ++t) {
    const Pose raw = Translated(base, Eigen::Vector3f(0.12f / 30.0f * static_cast<float>(t), 0.0f, 0.0f));
    Pose out = raw;
    lock.Apply(state, &out);
    ExpectCanonicalBones(skel, out, t);
    EXPECT_LE((out[kLeftAnkle] - out[kLeftHip]).norm(), reach + 1e-5f) << "frame " << t;
    EXPECT_LE(state.feet[0].correction.norm(), kFootLockMaxShift + 1e-6f);
  }
}

}  // namespace
}  // namespace dance::engine
