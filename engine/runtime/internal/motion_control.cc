#include "engine/runtime/internal/motion_control.h"

#include <algorithm>
#include <cmath>

#include "absl/strings/str_cat.h"
#include "engine/audio/feature_layout.h"
#include "engine/nn/status_macros.h"

namespace dance::engine {
namespace {

// The facing of the pelvis alone (the hips), 0 = +Z: the body frame the halves are composited in, so an
// upper body given relative to its hips comes out exactly so relative to the generated hips.
double HipYaw(const JointPositions& p) {
  const Eigen::Vector3d across = (p[1] - p[2]).cast<double>();  // left_hip - right_hip
  return std::atan2(-across.z(), across.x());
}

// Steering toward a known root or a path: the largest turn (rad per frame) and speed (m/s) it adds.
constexpr double kMaxSteerTurn = 0.3;
constexpr double kMaxSteerSpeed = 2.0;
// The fraction of the distance to the path closed per frame (before the speed cap).
constexpr double kTrajectoryGain = 0.2;
// The low-pass of the trajectory's correction velocity (per frame; 0 = none).
constexpr double kCorrectionSmoothing = 0.8;

double SmoothStep(double x) {
  x = std::clamp(x, 0.0, 1.0);
  return x * x * (3.0 - 2.0 * x);
}

// p in the body frame of (pelvis, yaw): R_y(-yaw) (p - pelvis).
Eigen::Vector3d ToBody(const Eigen::Vector3f& p, const Eigen::Vector3f& pelvis, double yaw) {
  const Eigen::Vector3d d = (p - pelvis).cast<double>();
  const double c = std::cos(yaw), s = std::sin(yaw);
  return {c * d.x() - s * d.z(), d.y(), s * d.x() + c * d.z()};
}

// The inverse: R_y(yaw) b + pelvis.
Eigen::Vector3f FromBody(const Eigen::Vector3d& b, const Eigen::Vector3f& pelvis, double yaw) {
  const double c = std::cos(yaw), s = std::sin(yaw);
  return Eigen::Vector3f(static_cast<float>(c * b.x() + s * b.z()), static_cast<float>(b.y()),
                         static_cast<float>(-s * b.x() + c * b.z())) + pelvis;
}

// Unit vector from a toward b by t along the great circle (a and b unit length).
Eigen::Vector3d Slerp(const Eigen::Vector3d& a, const Eigen::Vector3d& b, double t) {
  const double d = std::clamp(a.dot(b), -1.0, 1.0);
  const double angle = std::acos(d);
  if (angle < 1e-6) return a;
  Eigen::Vector3d to = b;
  if (M_PI - angle < 1e-3) {
    // Opposite: turn about an axis perpendicular to a (the vertical if a is not vertical).
    Eigen::Vector3d axis = a.cross(Eigen::Vector3d::UnitY());
    if (axis.norm() < 1e-6) axis = a.cross(Eigen::Vector3d::UnitX());
    to = Eigen::AngleAxisd(M_PI * t, axis.normalized()) * a;
    return to.normalized();
  }
  const double s = std::sin(angle);
  return (std::sin((1.0 - t) * angle) / s * a + std::sin(t * angle) / s * to).normalized();
}

}  // namespace

// Blends two poses by `t` (0 = a, 1 = b): the pelvis linearly, every bone's direction along the great
// circle, at the skeleton's bone lengths. (Blending positions would pass a limb that points the other way
// through zero length, where its direction, and the hand at its end, jumps.) Joints outside `mask` keep
// a's bone direction.
void MotionControl::BlendPoses(const JointPositions& a, const JointPositions& b, double t, JointMask mask,
                               JointPositions* out) const {
  const Skeleton& sk = model_->skeleton();
  JointPositions r;
  r[0] = (mask & 1) ? Eigen::Vector3f(a[0] + static_cast<float>(t) * (b[0] - a[0])) : a[0];
  for (int j = 1; j < kNumJoints; ++j) {
    const int parent = sk.parents[j];
    Eigen::Vector3d da = (a[j] - a[parent]).cast<double>();
    Eigen::Vector3d db = (b[j] - b[parent]).cast<double>();
    const double la = da.norm(), lb = db.norm();
    Eigen::Vector3d dir = la > 1e-9 ? Eigen::Vector3d(da / la) : Eigen::Vector3d::UnitY();
    if ((mask >> j & 1) && lb > 1e-9) dir = Slerp(dir, db / lb, t);
    r[j] = r[parent] + (sk.bone_lengths[j] * dir).cast<float>();
  }
  *out = r;
}

MotionControl::MotionControl(const Model& model) : model_(&model) {}

absl::StatusOr<MotionControl> MotionControl::Create(const Model& model, const Controls& controls) {
  MotionControl mc(model);
  DANCE_ASSIGN_OR_RETURN(mc.initial_plan_, mc.MakePlan(controls));
  mc.state_.plan = mc.initial_plan_;
  return mc;
}

absl::Status MotionControl::SetControls(const Controls& controls) {
  DANCE_ASSIGN_OR_RETURN(state_.plan, MakePlan(controls));
  return absl::OkStatus();
}

absl::StatusOr<std::shared_ptr<const ControlPlan>> MotionControl::MakePlan(const Controls& controls) const {
  DANCE_RETURN_IF_ERROR(ValidateControls(controls));
  if (controls.empty()) return std::shared_ptr<const ControlPlan>();
  auto plan = std::make_shared<ControlPlan>();
  plan->controls = controls;
  const MotionTrack& t = plan->controls.motion;
  if (!t.empty()) {
    if (model_->upper_encoder() == nullptr || model_->lower_encoder() == nullptr) {
      return absl::FailedPreconditionError(
          absl::StrCat("controls: model '", model_->model_id(), "' has no VQ encoders to read given motion with"));
    }
    const JointMask stream_mask[2] = {UpperMask(), LowerMask()};
    const VqEncoder* encoder[2] = {model_->upper_encoder(), model_->lower_encoder()};
    const int n = static_cast<int>(t.positions.size());
    for (int stream = 0; stream < 2; ++stream) {
      std::vector<int>& codes = plan->codes[stream];
      codes.assign(n, -1);
      plan->forceable[stream].assign(n, 0);
      // Each run of frames that know the whole stream is encoded on its own (the encoder looks ahead and
      // behind within the run; a single key frame is held for one code).
      for (int a = 0; a < n;) {
        if ((t.known[a] & stream_mask[stream]) != stream_mask[stream]) {
          ++a;
          continue;
        }
        int b = a;
        while (b < n && (t.known[b] & stream_mask[stream]) == stream_mask[stream]) ++b;
        const std::vector<JointPositions> run(t.positions.begin() + a, t.positions.begin() + b);
        const PoseFeatures f = EncodePoseFeatures(run);
        const std::vector<int> run_codes = encoder[stream]->Encode(stream == 0 ? f.upper : f.lower);
        for (int i = a; i < b; ++i) {
          codes[i] = run_codes[(i - a) / encoder[stream]->downsample()];
          plan->forceable[stream][i] = b - a >= encoder[stream]->downsample();
        }
        a = b;
      }
    }
    for (int i = 0; i < n; ++i) {
      if (t.known[i] != 0) plan->known_frames.push_back(t.first_frame + i);
    }
  }
  return std::shared_ptr<const ControlPlan>(std::move(plan));
}

int MotionControl::ForcedCode(int stream, int64_t m) const {
  const MotionTrack& t = plan().controls.motion;
  if (m < t.first_frame || m >= t.end_frame() || !plan().forceable[stream][m - t.first_frame]) return -1;
  return plan().codes[stream][m - t.first_frame];
}

absl::Status MotionControl::Validate(const MotionControlState& state) const {
  if (state.plan == nullptr) return absl::OkStatus();
  const int k = model_->config().codebook_size;
  for (const std::vector<int>& codes : state.plan->codes) {
    for (int code : codes) {
      if (code < -1 || code >= k) {
        return absl::InvalidArgumentError("session restore: snapshot has control codes outside this model's codebook");
      }
    }
  }
  return absl::OkStatus();
}

int MotionControl::GivenCode(int stream, int64_t m) const {
  const MotionTrack& t = plan().controls.motion;
  if (m < t.first_frame || m >= t.end_frame()) return -1;
  return plan().codes[stream][m - t.first_frame];
}

Eigen::Vector2d MotionControl::PathAt(double t_s) const {
  const auto& path = plan().controls.trajectory;
  if (t_s <= path.front().t_s) return {path.front().x, path.front().z};
  if (t_s >= path.back().t_s) return {path.back().x, path.back().z};
  const auto it = std::upper_bound(path.begin(), path.end(), t_s,
                                   [](double t, const TrajectoryPoint& p) { return t < p.t_s; });
  const TrajectoryPoint& b = *it;
  const TrajectoryPoint& a = *(it - 1);
  const double w = (t_s - a.t_s) / (b.t_s - a.t_s);
  return {a.x + w * (b.x - a.x), a.z + w * (b.z - a.z)};
}

bool MotionControl::PathFacingAt(double t_s, double* facing) const {
  const auto& path = plan().controls.trajectory;
  const TrajectoryPoint* before = nullptr;
  const TrajectoryPoint* after = nullptr;
  for (const TrajectoryPoint& p : path) {
    if (!p.facing) continue;
    if (p.t_s <= t_s) before = &p;
    if (p.t_s >= t_s && after == nullptr) after = &p;
  }
  if (before == nullptr && after == nullptr) return false;
  if (before == nullptr || after == nullptr || before == after) {
    *facing = *(before != nullptr ? before : after)->facing;
    return true;
  }
  const double w = (t_s - before->t_s) / (after->t_s - before->t_s);
  *facing = *before->facing + w * WrapAngle(*after->facing - *before->facing);
  return true;
}

void MotionControl::Align(JointPositions& p) const {
  const double c = std::cos(state_.yaw), s = std::sin(state_.yaw);
  for (Eigen::Vector3f& q : p) {
    const double x = q.x(), z = q.z();
    q.x() = static_cast<float>(c * x + s * z + state_.x);
    q.z() = static_cast<float>(-s * x + c * z + state_.z);
  }
}

StepControl MotionControl::ForStep(double first_real, double last_real, const PoseState& root, double rate,
                                   const VqDecoderState& lower_state, const float* lower_logits) {
  StepControl sc;
  if (!active()) return sc;
  const ControlWeights& w = plan().controls.weights;
  const int64_t lo = static_cast<int64_t>(std::floor(first_real));
  const int64_t hi = static_cast<int64_t>(std::ceil(last_real));
  if (!plan().controls.motion.empty()) {
    const int64_t mid = static_cast<int64_t>(std::lround(0.5 * (first_real + last_real)));
    for (int stream = 0; stream < 2; ++stream) {
      // Forced: the given code at the frame of the emitted period nearest its middle that has one.
      int best = -1;
      int64_t best_distance = 0;
      for (int64_t m = lo; m <= hi; ++m) {
        const int code = ForcedCode(stream, m);
        if (code >= 0 && (best < 0 || std::abs(m - mid) < best_distance)) {
          best = code;
          best_distance = std::abs(m - mid);
        }
      }
      sc.forced[stream] = best;
    }
    // Pulled: toward the codes of the next known frame within the horizon.
    const auto next = std::upper_bound(plan().known_frames.begin(), plan().known_frames.end(), hi);
    if (next != plan().known_frames.end() && *next - hi <= std::lround(w.key_horizon_s * audio::kFrameRate)) {
      for (int stream = 0; stream < 2; ++stream) {
        if (sc.forced[stream] < 0) sc.pull[stream] = GivenCode(stream, *next);
      }
      sc.pull_weight = w.key_pull;
    }
  }
  if (!plan().controls.trajectory.empty() && sc.forced[1] < 0 && w.trajectory_weight > 0.0f) {
    // The root in output coordinates now, and the path point a lead ahead of the emitted period.
    const double c = std::cos(state_.yaw), s = std::sin(state_.yaw);
    const Eigen::Vector2d here(c * root.root_x + s * root.root_z + state_.x, -s * root.root_x + c * root.root_z + state_.z);
    const double yaw = root.yaw + state_.yaw;
    const double lead_frames = w.trajectory_lead_s * audio::kFrameRate + 0.5 * (last_real - first_real);
    const double aim_t = (0.5 * (first_real + last_real)) / audio::kFrameRate + w.trajectory_lead_s;
    const Eigen::Vector2d d = PathAt(aim_t) - here;
    // Desired velocity in the facing frame, per warped frame (the codes' table is in warped frames).
    const double cy = std::cos(yaw), sy = std::sin(yaw);
    const double vx = (cy * d.x() - sy * d.y()) / lead_frames / rate;
    const double vz = (sy * d.x() + cy * d.y()) / lead_frames / rate;
    double facing = 0.0;
    const bool steer_facing = PathFacingAt(aim_t, &facing);
    const double yaw_rate = steer_facing ? WrapAngle(facing - yaw) / lead_frames / rate : 0.0;
    // Every code is first scored by its held root motion (Model::lower_code_motion, a rough guide: in a
    // dance a code's motion depends on what came before); the codes most likely under logit + that score
    // are then decoded one step from the decoder's state now and scored by the root motion they really
    // decode to (mean vx, vz, yaw rate over the period).
    const int k = model_->config().codebook_size;
    const int n = std::min(kTrajectoryCandidates, k);
    constexpr double kSpeedScale = 0.01;  // m per frame: a bias of -weight per 1 cm/frame of speed error
    constexpr double kTurnScale = 0.02;   // rad per frame
    constexpr double kMaxCost = 25.0;
    auto bias_of = [&](const Eigen::Vector3f& motion) {
      const double ex = (motion.x() - vx) / kSpeedScale, ez = (motion.y() - vz) / kSpeedScale;
      double cost = ex * ex + ez * ez;
      if (steer_facing) cost += std::pow((motion.z() - yaw_rate) / kTurnScale, 2);
      return static_cast<float>(-w.trajectory_weight * std::min(cost, kMaxCost));
    };
    const std::vector<Eigen::Vector3f>& held = model_->lower_code_motion();
    lower_bias_.resize(k);
    for (int i = 0; i < k; ++i) lower_bias_[i] = bias_of(held[i]);
    candidates_.resize(k);
    for (int i = 0; i < k; ++i) candidates_[i] = i;
    auto score = [&](int i) { return lower_logits[i] + lower_bias_[i]; };
    std::partial_sort(candidates_.begin(), candidates_.begin() + n, candidates_.end(),
                      [&](int a, int b) { return score(a) > score(b) || (score(a) == score(b) && a < b); });
    candidates_.resize(n);
    candidate_states_.assign(n, lower_state);
    candidate_ptrs_.resize(n);
    for (int i = 0; i < n; ++i) candidate_ptrs_[i] = &candidate_states_[i];
    const auto frames = model_->lower_decoder().DecodeBatch(candidates_, candidate_ptrs_, candidate_scratch_);
    const int fpc = model_->lower_decoder().frames_per_code();
    for (int i = 0; i < n; ++i) {
      lower_bias_[candidates_[i]] = bias_of(frames.block(kLowerHeightIndex - 3, i * fpc, 3, fpc).rowwise().mean());
    }
    sc.lower_bias = lower_bias_.data();
  }
  return sc;
}

void MotionControl::TurnAndMoveAlignment(double dyaw, const Eigen::Vector3f& pivot, double dx, double dz) {
  // A' = T(pivot) R(dyaw) T(-pivot) A, then + (dx, dz): t' = R(dyaw) (t - pivot) + pivot + d.
  const double c = std::cos(dyaw), s = std::sin(dyaw);
  const double tx = state_.x - pivot.x(), tz = state_.z - pivot.z();
  state_.yaw += dyaw;
  state_.x = c * tx + s * tz + pivot.x() + dx;
  state_.z = -s * tx + c * tz + pivot.z() + dz;
}

void MotionControl::TurnAndMove(double dyaw, const Eigen::Vector3f& pivot, double dx, double dz, JointPositions& p) {
  TurnAndMoveAlignment(dyaw, pivot, dx, dz);
  const double c = std::cos(dyaw), s = std::sin(dyaw);
  for (Eigen::Vector3f& q : p) {
    const double qx = q.x() - pivot.x(), qz = q.z() - pivot.z();
    q.x() = static_cast<float>(c * qx + s * qz + pivot.x() + dx);
    q.z() = static_cast<float>(-s * qx + c * qz + pivot.z() + dz);
  }
}

bool MotionControl::Composite(PoseFrame& frame) {
  if (!active()) return false;
  const ControlWeights& w = plan().controls.weights;
  const MotionTrack& t = plan().controls.motion;
  const int64_t m = frame.index;
  JointPositions& p = frame.positions;
  Align(p);
  const JointMask known = t.KnownAt(m);
  const auto next = std::upper_bound(plan().known_frames.begin(), plan().known_frames.end(), m);
  const bool next_root = next != plan().known_frames.end() && (t.KnownAt(*next) & 1);
  if (!(known & 1)) {
    if (next_root) {
      // Steer toward the next known root: each frame closes a share of the remaining offset in position
      // and facing (so the correction spreads over the gap), capped in speed.
      const JointPositions& key = t.positions[*next - t.first_frame];
      // (Twice the even share, so the offset is closed by half-way and then tracked: the generated dancer
      // keeps turning on its own, and an even share left most of a turn to the last frames.)
      const double left = std::max(1.0, 0.5 * static_cast<double>(*next - m));
      const double dyaw = std::clamp(WrapAngle(HipYaw(key) - HipYaw(p)) / left, -kMaxSteerTurn, kMaxSteerTurn);
      Eigen::Vector2d d(key[0].x() - p[0].x(), key[0].z() - p[0].z());
      d /= left;
      const double cap = kMaxSteerSpeed / audio::kFrameRate;
      if (d.norm() > cap) d *= cap / d.norm();
      TurnAndMove(dyaw, p[0], d.x(), d.y(), p);
    } else if (!plan().controls.trajectory.empty()) {
      // Trajectory: a bounded correction of the alignment toward the path.
      const double t_s = static_cast<double>(m) / audio::kFrameRate;
      if (!state_.on_path) {
        // The dance starts on the path (its first point if the path starts later): moved there at the
        // first frame, not steered from afar.
        const Eigen::Vector2d e = PathAt(t_s) - Eigen::Vector2d(p[0].x(), p[0].z());
        TurnAndMove(0.0, p[0], e.x(), e.y(), p);
        state_.on_path = true;
      }
      {
        // (Before the path's first point and after its last the dancer is held around that point.)
        // The correction's velocity follows the wanted one through a low-pass (a step change of it is
        // a jerk the eye sees as shaking).
        Eigen::Vector2d e = kTrajectoryGain * (PathAt(t_s) - Eigen::Vector2d(p[0].x(), p[0].z()));
        // The cap: root_correction_mps, or 1.5x the path's own speed where the path is faster (a fast
        // travelling dance outran a fixed cap: the tango's real root reaches 2.9 m/s).
        const double path_speed = (PathAt(t_s + 0.1) - PathAt(t_s - 0.1)).norm() / 0.2;
        const double cap = std::max<double>(w.root_correction_mps, 1.5 * path_speed) / audio::kFrameRate;
        if (e.norm() > cap) e *= cap / e.norm();
        e = kCorrectionSmoothing * Eigen::Vector2d(state_.correction_x, state_.correction_z) +
            (1.0 - kCorrectionSmoothing) * e;
        state_.correction_x = e.x();
        state_.correction_z = e.y();
        double dyaw = 0.0, facing = 0.0;
        if (PathFacingAt(t_s, &facing)) {
          dyaw = std::clamp(kTrajectoryGain * WrapAngle(facing - HipYaw(p)), -kMaxSteerTurn, kMaxSteerTurn);
        }
        TurnAndMove(dyaw, p[0], e.x(), e.y(), p);
      }
    }
  }
  if (known != 0) {
    const JointPositions& given = t.positions[m - t.first_frame];
    const double given_yaw = HipYaw(given);
    const double gen_yaw = HipYaw(p);
    if (known & 1) {
      // The pelvis is given: the given body frame holds; unknown joints are the generated ones moved into
      // it, and the generated dance is re-aligned (turned about its pelvis and moved onto the given one)
      // so it continues from the given root.
      const Eigen::Vector3f pelvis = p[0];
      TurnAndMoveAlignment(WrapAngle(given_yaw - gen_yaw), pelvis, given[0].x() - pelvis.x(),
                           given[0].z() - pelvis.z());
      for (int j = 0; j < kNumJoints; ++j) {
        p[j] = (known >> j & 1) ? given[j] : FromBody(ToBody(p[j], pelvis, gen_yaw), given[0], given_yaw);
      }
    } else {
      // The pelvis is generated: known joints are placed relative to it as they are to the given pelvis.
      for (int j = 0; j < kNumJoints; ++j) {
        if (known >> j & 1) p[j] = FromBody(ToBody(given[j], given[0], given_yaw), p[0], gen_yaw);
      }
    }
    state_.last_known = m;
    state_.last_pose = p;
    return (known & LowerMask()) == LowerMask();
  }
  const double gen_yaw = HipYaw(p);
  // Out of a known frame: its pose, carried by the generated root, fades into the generated pose.
  const double out_frames = w.blend_out_s * audio::kFrameRate;
  if (state_.last_known >= 0 && m - state_.last_known < out_frames) {
    const double a = SmoothStep(static_cast<double>(m - state_.last_known) / out_frames);
    const double last_yaw = HipYaw(state_.last_pose);
    // The known frame's pose carried on the generated root and facing (its height too), fading into the
    // generated pose bone by bone.
    JointPositions carried;
    for (int j = 0; j < kNumJoints; ++j) {
      carried[j] = FromBody(ToBody(state_.last_pose[j], state_.last_pose[0], last_yaw), p[0], gen_yaw);
    }
    carried[0].y() = state_.last_pose[0].y();
    for (int j = 1; j < kNumJoints; ++j) carried[j].y() += state_.last_pose[0].y() - p[0].y();
    BlendPoses(carried, p, a, kAllJoints, &p);
  }
  // Into the next known frame: a known root, the whole body blends toward the key (the root was steered
  // close above; bone directions, not a facing angle, so nothing wraps around); otherwise the key's known
  // joints, placed on the generated pelvis and facing.
  const double in_frames = w.blend_in_s * audio::kFrameRate;
  if (next != plan().known_frames.end() && *next - m < in_frames) {
    const JointPositions& key = t.positions[*next - t.first_frame];
    const JointMask key_known = t.KnownAt(*next);
    const float b = static_cast<float>(SmoothStep(1.0 - static_cast<double>(*next - m) / in_frames));
    if (key_known & 1) {
      BlendPoses(p, key, b, key_known, &p);
    } else {
      JointPositions placed = p;  // the key's known joints placed on the generated pelvis and facing
      const double key_yaw = HipYaw(key);
      for (int j = 1; j < kNumJoints; ++j) {
        if (key_known >> j & 1) placed[j] = FromBody(ToBody(key[j], key[0], key_yaw), p[0], gen_yaw);
      }
      BlendPoses(p, placed, b, key_known, &p);
    }
  }
  return false;
}

}  // namespace dance::engine
