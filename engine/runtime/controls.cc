#include "engine/runtime/controls.h"

#include <algorithm>
#include <cmath>

#include "absl/strings/str_cat.h"

namespace dance::engine {

JointMask UpperMask() {
  JointMask m = 0;
  for (int j : kUpperJoints) m |= JointMask{1} << j;
  return m;
}

JointMask LowerMask() {
  JointMask m = 0;
  for (int j : kLowerJoints) m |= JointMask{1} << j;
  return m;
}

MotionTrack SeedTrack(std::vector<JointPositions> clip, int64_t first_frame) {
  MotionTrack t;
  t.first_frame = first_frame;
  t.known.assign(clip.size(), kAllJoints);
  t.positions = std::move(clip);
  return t;
}

MotionTrack GivenHalfTrack(std::vector<JointPositions> motion, int64_t first_frame, bool upper) {
  MotionTrack t;
  t.first_frame = first_frame;
  t.known.assign(motion.size(), upper ? UpperMask() : LowerMask());
  t.positions = std::move(motion);
  return t;
}

absl::StatusOr<MotionTrack> KeyframeTrack(const std::vector<JointPositions>& poses,
                                          const std::vector<int64_t>& frames) {
  if (poses.size() != frames.size()) {
    return absl::InvalidArgumentError(
        absl::StrCat("keyframes: ", poses.size(), " poses but ", frames.size(), " times"));
  }
  MotionTrack t;
  if (poses.empty()) return t;
  for (size_t i = 0; i < frames.size(); ++i) {
    if (frames[i] < 0) return absl::InvalidArgumentError(absl::StrCat("keyframes: key ", i, " is before the audio"));
    if (i > 0 && frames[i] - frames[i - 1] < 4) {
      return absl::InvalidArgumentError(absl::StrCat("keyframes: keys ", i - 1, " and ", i, " (frames ", frames[i - 1],
                                                     ", ", frames[i], ") are closer than one step (4 frames)"));
    }
  }
  if (frames.back() - frames.front() >= kMaxTrackFrames) {
    return absl::InvalidArgumentError("keyframes: the keys span more than 3 hours");
  }
  t.first_frame = frames.front();
  const size_t n = static_cast<size_t>(frames.back() - frames.front() + 1);
  t.positions.assign(n, poses.front());
  t.known.assign(n, 0);
  for (size_t i = 0; i < frames.size(); ++i) {
    t.positions[frames[i] - t.first_frame] = poses[i];
    t.known[frames[i] - t.first_frame] = kAllJoints;
  }
  return t;
}

MotionTrack MaskedTrack(std::vector<JointPositions> dance, int64_t first_frame, std::vector<JointMask> known) {
  MotionTrack t;
  t.first_frame = first_frame;
  t.positions = std::move(dance);
  t.known = std::move(known);
  return t;
}

MotionTrack CombineTracks(const MotionTrack& a, const MotionTrack& b) {
  if (a.empty()) return b;
  if (b.empty()) return a;
  MotionTrack t;
  t.first_frame = std::min(a.first_frame, b.first_frame);
  const int64_t end = std::max(a.end_frame(), b.end_frame());
  t.positions.resize(static_cast<size_t>(end - t.first_frame));
  t.known.assign(t.positions.size(), 0);
  for (int64_t m = t.first_frame; m < end; ++m) {
    const size_t i = static_cast<size_t>(m - t.first_frame);
    const JointMask ka = a.KnownAt(m), kb = b.KnownAt(m);
    // Positions: b's where b has the frame, else a's (unknown joints keep a plausible body for encoding).
    if (m >= b.first_frame && m < b.end_frame()) {
      t.positions[i] = b.positions[m - b.first_frame];
    } else if (m >= a.first_frame && m < a.end_frame()) {
      t.positions[i] = a.positions[m - a.first_frame];
    }
    if (ka != 0 && m >= a.first_frame && m < a.end_frame()) {
      for (int j = 0; j < kNumJoints; ++j) {
        if ((ka >> j & 1) && !(kb >> j & 1)) t.positions[i][j] = a.positions[m - a.first_frame][j];
      }
    }
    t.known[i] = ka | kb;
  }
  return t;
}

absl::Status ValidateControls(const Controls& c) {
  const MotionTrack& t = c.motion;
  if (t.positions.size() != t.known.size()) {
    return absl::InvalidArgumentError(absl::StrCat("controls: motion has ", t.positions.size(), " frames but ",
                                                   t.known.size(), " masks"));
  }
  if (!t.empty() && t.first_frame < 0) return absl::InvalidArgumentError("controls: motion starts before the audio");
  if (static_cast<int64_t>(t.positions.size()) > kMaxTrackFrames || t.first_frame > kMaxTrackFrames) {
    return absl::InvalidArgumentError("controls: motion spans or starts more than 3 hours into the audio");
  }
  for (size_t i = 0; i < t.positions.size(); ++i) {
    if (t.known[i] & ~kAllJoints) {
      return absl::InvalidArgumentError(absl::StrCat("controls: frame ", i, "'s mask names joints beyond the 24"));
    }
    for (int j = 0; j < kNumJoints; ++j) {
      const Eigen::Vector3f& p = t.positions[i][j];
      if (!p.allFinite() || p.cwiseAbs().maxCoeff() > 100.0f) {
        return absl::InvalidArgumentError(absl::StrCat("controls: motion frame ", i, " joint ", j,
                                                       " is not a position within 100 m (", p.x(), ", ", p.y(),
                                                       ", ", p.z(), ")"));
      }
    }
  }
  for (size_t i = 0; i < c.trajectory.size(); ++i) {
    const TrajectoryPoint& p = c.trajectory[i];
    if (!std::isfinite(p.t_s) || p.t_s < 0.0 || p.t_s > 1e6 || !std::isfinite(p.x) || !std::isfinite(p.z) ||
        std::abs(p.x) > 1000.0f || std::abs(p.z) > 1000.0f || (p.facing && !std::isfinite(*p.facing))) {
      return absl::InvalidArgumentError(absl::StrCat("controls: trajectory point ", i,
                                                     " has a time outside [0, 1e6] s or a non-finite or absurd coordinate"));
    }
    if (i > 0 && !(p.t_s > c.trajectory[i - 1].t_s)) {
      return absl::InvalidArgumentError(absl::StrCat("controls: trajectory point ", i, " (t = ", p.t_s,
                                                     " s) is not after point ", i - 1, " (t = ",
                                                     c.trajectory[i - 1].t_s, " s)"));
    }
  }
  const ControlWeights& w = c.weights;
  for (float v : {w.key_pull, w.key_horizon_s, w.blend_in_s, w.blend_out_s, w.trajectory_weight, w.trajectory_lead_s,
                  w.root_correction_mps}) {
    if (!std::isfinite(v) || v < 0.0f || v > 100.0f) {
      return absl::InvalidArgumentError("controls: a control weight is outside [0, 100]");
    }
  }
  if (w.trajectory_lead_s < 0.1f) return absl::InvalidArgumentError("controls: trajectory_lead_s must be >= 0.1");
  return absl::OkStatus();
}

}  // namespace dance::engine
