#include "engine/vq/foot_lock.h"

#include <algorithm>
#include <cmath>

#include "Eigen/Geometry"

namespace dance::engine {
namespace {

constexpr float kFramesPerSecond = 30.0f;
constexpr float kReach = 0.999f;  // the longest hip-to-ankle distance used, as a share of thigh + shin
constexpr float kStraightLegBend = 0.01f;  // metres of forward added to the decoded knee's bend

// 1 at or below `full`, 0 at or above `none`, linear between.
float Ramp(float x, float full, float none) { return std::clamp((none - x) / (none - full), 0.0f, 1.0f); }

// The largest s in [0, 1] with |e + s c| <= reach, given |e| <= reach (e = ankle - hip, c the shift).
float ReachableShare(const Eigen::Vector3f& e, const Eigen::Vector3f& c, float reach) {
  if ((e + c).norm() <= reach) return 1.0f;
  const float a = c.squaredNorm(), b = 2.0f * e.dot(c), k = e.squaredNorm() - reach * reach;
  if (a < 1e-12f || k > 0.0f) return 0.0f;  // no shift, or the decoded ankle itself is out of reach
  const float s = (-b + std::sqrt(std::max(b * b - 4.0f * a * k, 0.0f))) / (2.0f * a);
  return std::clamp(s, 0.0f, 1.0f);
}

}  // namespace

FootLock::FootLock(const Skeleton& skeleton) {
  constexpr int kHip[2] = {1, 2}, kKnee[2] = {4, 5}, kAnkle[2] = {7, 8}, kFoot[2] = {10, 11};
  for (int side = 0; side < 2; ++side) {
    legs_[side] = {kHip[side], kKnee[side], kAnkle[side], kFoot[side], skeleton.bone_lengths[kKnee[side]],
                   skeleton.bone_lengths[kAnkle[side]]};
  }
}

float FootLock::ContactWeight(float foot_height, float smoothed_speed) {
  return Ramp(foot_height, kFootLockHeightFull, kFootLockHeightNone) *
         Ramp(smoothed_speed, kFootLockSpeedFull, kFootLockSpeedNone);
}

void FootLock::Apply(FootLockState& state, std::array<Eigen::Vector3f, kNumJoints>* positions) const {
  std::array<Eigen::Vector3f, kNumJoints>& p = *positions;
  for (int side = 0; side < 2; ++side) {
    const Leg& leg = legs_[side];
    FootLockState::Foot& foot = state.feet[side];
    const Eigen::Vector2f raw(0.5f * (p[leg.ankle].x() + p[leg.foot].x()),
                              0.5f * (p[leg.ankle].z() + p[leg.foot].z()));
    const Eigen::Vector2f moved = foot.has_previous ? Eigen::Vector2f(raw - foot.previous) : Eigen::Vector2f::Zero();
    foot.previous = raw;
    foot.has_previous = true;
    foot.speed += kFootLockSpeedSmoothing * (moved.norm() * kFramesPerSecond - foot.speed);
    const Eigen::Vector3f hip = p[leg.hip];
    const Eigen::Vector3f ankle = p[leg.ankle];
    const float length = leg.thigh + leg.shin;
    // A hold that would stretch the leg toward straight lets go gradually (the room to reach sideways
    // vanishes in the last percent of the leg's length); a hold that bends it (a straight decoded leg
    // whose foot stays behind) is not limited.
    const float decoded = (ankle - hip).norm();
    const float held = (ankle + Eigen::Vector3f(foot.correction.x(), 0.0f, foot.correction.y()) - hip).norm();
    const float extension =
        held <= decoded ? 1.0f : Ramp(held / length, kFootLockExtensionFull, kFootLockExtensionNone);
    const float w = ContactWeight(p[leg.foot].y(), foot.speed) * extension;
    foot.correction -= w * moved;
    foot.correction *= 1.0f - kFootLockRelease * (1.0f - w);
    const float n = foot.correction.norm();
    if (n > kFootLockMaxShift) foot.correction *= kFootLockMaxShift / n;

    Eigen::Vector3f shift(foot.correction.x(), 0.0f, foot.correction.y());
    // At most as long as the decoded leg or 0.999 of the leg, whichever is longer: a decoded leg that is
    // itself straight keeps the holds that do not lengthen it, so its correction shrinks smoothly.
    const float share = ReachableShare(ankle - hip, shift, std::max(kReach * length, decoded));
    if (share < 1.0f) {
      foot.correction *= share;
      shift *= share;
    }
    if (shift.squaredNorm() < 1e-12f) continue;

    // Two-bone IK: the knee on the circle of points at `thigh` from the hip and `shin` from the target.
    const Eigen::Vector3f target = ankle + shift;
    const Eigen::Vector3f to_target = target - hip;
    const float d = to_target.norm();
    if (d < std::abs(leg.thigh - leg.shin) + 1e-3f) {  // folded tighter than the leg can: leave it as decoded
      foot.correction.setZero();
      continue;
    }
    const Eigen::Vector3f u = to_target / d;
    const float along = (leg.thigh * leg.thigh - leg.shin * leg.shin + d * d) / (2.0f * d);
    const float radius = std::sqrt(std::max(leg.thigh * leg.thigh - along * along, 0.0f));
    // The bend's direction: the decoded knee's offset from the decoded hip-ankle line, its backward part
    // dropped (knees do not bend backwards; a decoded knee a centimetre behind the line would otherwise
    // flip the bend), plus kStraightLegBend of the body's forward (left-right axis x up), which decides
    // for a straight decoded leg and keeps the direction continuous.
    const Eigen::Vector3f raw_axis = (ankle - hip).normalized();
    const Eigen::Vector3f knee_rel = p[leg.knee] - hip;
    const Eigen::Vector3f across = p[legs_[0].hip] - p[legs_[1].hip];
    const Eigen::Vector3f forward = across.cross(Eigen::Vector3f::UnitY()).normalized();
    Eigen::Vector3f pole = knee_rel - knee_rel.dot(raw_axis) * raw_axis;
    pole -= std::min(pole.dot(forward), 0.0f) * forward;
    pole += kStraightLegBend * forward;
    pole -= pole.dot(u) * u;
    const float pole_norm = pole.norm();
    pole = pole_norm > 1e-6f ? Eigen::Vector3f(pole / pole_norm) : Eigen::Vector3f(u.unitOrthogonal());
    p[leg.knee] = hip + along * u + radius * pole;
    p[leg.ankle] = target;
    p[leg.foot] += shift;
  }
}

}  // namespace dance::engine
