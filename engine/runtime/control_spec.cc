#include "engine/runtime/control_spec.h"

#include <cmath>

#include "absl/strings/str_cat.h"

namespace dance::engine {
namespace {

constexpr double kFps = 30.0;

// The motion of `m` as a MotionFile on the audio timeline.
absl::StatusOr<MotionFile> Load(const MotionSource& m) {
  if (!std::isfinite(m.start_s) || std::abs(m.start_s) > 1e6) {
    return absl::InvalidArgumentError(absl::StrCat("'", m.name, "': start time ", m.start_s, " s is not usable"));
  }
  MotionFile f;
  if (!m.text.empty()) {
    if (!m.positions.empty() || !m.times_s.empty()) {
      return absl::InvalidArgumentError(absl::StrCat("'", m.name, "': give either a file or poses, not both"));
    }
    absl::StatusOr<MotionFile> parsed = ParseMotionText(m.text, m.name);
    if (!parsed.ok()) return parsed.status();
    f = *std::move(parsed);
    f.offset_s += m.start_s;
    for (double& t : f.times_s) t += m.start_s;
    f.first_frame = std::lround(f.offset_s * kFps);
  } else {
    f.positions = m.positions;
    f.offset_s = m.start_s;
    f.first_frame = std::lround(m.start_s * kFps);
    if (!m.times_s.empty()) {
      if (m.times_s.size() != m.positions.size()) {
        return absl::InvalidArgumentError(absl::StrCat("'", m.name, "': ", m.times_s.size(), " times for ",
                                                       m.positions.size(), " poses"));
      }
      for (double t : m.times_s) {
        if (!std::isfinite(t) || t < 0.0 || t > 1e6) {
          return absl::InvalidArgumentError(absl::StrCat("'", m.name, "': a pose time is not in [0, 1e6] s"));
        }
      }
      f.times_s = m.times_s;
    }
    for (size_t i = 0; i < f.positions.size(); ++i) {
      for (int j = 0; j < kNumJoints; ++j) {
        if (!f.positions[i][j].allFinite() || f.positions[i][j].cwiseAbs().maxCoeff() > 100.0f) {
          return absl::InvalidArgumentError(absl::StrCat("'", m.name, "': pose ", i, " joint ", j,
                                                         " is not a finite position within 100 m"));
        }
      }
    }
  }
  if (f.positions.empty()) return absl::InvalidArgumentError(absl::StrCat("'", m.name, "': no frames"));
  if (f.first_frame < 0 && f.times_s.empty()) {
    return absl::InvalidArgumentError(absl::StrCat("'", m.name, "': starts before the audio (", f.offset_s, " s)"));
  }
  return f;
}

}  // namespace

absl::StatusOr<Controls> BuildControls(const ControlSpec& spec, const BuildOptions& options,
                                       std::vector<std::string>* names) {
  Controls c;
  std::vector<std::string> present;
  // Every motion must start within the song (ValidateControls bounds how long a track may be).
  const double song_frames = std::ceil(options.duration_s * kFps);
  auto load = [&](const MotionSource& m, const char* name) -> absl::StatusOr<MotionFile> {
    present.push_back(name);
    absl::StatusOr<MotionFile> f = Load(m);
    if (!f.ok()) return f.status();
    const int64_t first = f->times_s.empty() ? f->first_frame : std::lround(f->times_s.front() * kFps);
    if (static_cast<double>(first) >= song_frames) {
      return absl::InvalidArgumentError(absl::StrCat("'", m.name, "': the motion starts at ", first / kFps,
                                                     " s, past the song's ", options.duration_s, " s"));
    }
    return f;
  };
  if (!spec.inpaint.empty()) {
    absl::StatusOr<MotionFile> dance = load(spec.inpaint, "inpaint");
    if (!dance.ok()) return dance.status();
    absl::StatusOr<std::vector<JointMask>> mask =
        MaskFromSpans(spec.inpaint_known, *dance, spec.mask_name);
    if (!mask.ok()) return mask.status();
    c.motion = CombineTracks(c.motion, MaskedTrack(dance->positions, dance->first_frame, *mask));
  } else if (!spec.inpaint_known.empty()) {
    return absl::InvalidArgumentError("an inpainting mask needs the dance it masks (inpaint)");
  }
  for (const auto& [m, upper] : {std::pair{&spec.given_upper, true}, std::pair{&spec.given_lower, false}}) {
    if (m->empty()) continue;
    absl::StatusOr<MotionFile> f = load(*m, upper ? "given_upper" : "given_lower");
    if (!f.ok()) return f.status();
    c.motion = CombineTracks(c.motion, GivenHalfTrack(f->positions, f->first_frame, upper));
  }
  if (!spec.seed.empty()) {
    absl::StatusOr<MotionFile> f = load(spec.seed, "seed_motion");
    if (!f.ok()) return f.status();
    if (f->positions.size() < 4) {
      return absl::InvalidArgumentError(absl::StrCat("'", spec.seed.name, "': a seed clip needs >= 4 frames"));
    }
    c.motion = CombineTracks(c.motion,
                             SeedTrack(f->positions, std::max(f->first_frame, options.seed_not_before_frame)));
  }
  if (!spec.keyframes.empty()) {
    absl::StatusOr<MotionFile> f = load(spec.keyframes, "keyframes");
    if (!f.ok()) return f.status();
    if (f->times_s.empty()) {
      return absl::InvalidArgumentError(absl::StrCat("'", spec.keyframes.name, "': keyframes need times (\"times_s\")"));
    }
    std::vector<int64_t> frames;
    for (double t : f->times_s) frames.push_back(std::lround(t * kFps));
    absl::StatusOr<MotionTrack> keys = KeyframeTrack(f->positions, frames);
    if (!keys.ok()) {
      return absl::InvalidArgumentError(absl::StrCat("'", spec.keyframes.name, "': ", keys.status().message()));
    }
    c.motion = CombineTracks(c.motion, *keys);
  }
  if (!spec.trajectory.empty()) {
    present.push_back("trajectory");
    if (spec.trajectory.size() < 2) return absl::InvalidArgumentError("trajectory: a path needs >= 2 points");
    if (spec.trajectory.back().t_s > options.duration_s + 1.0) {
      return absl::InvalidArgumentError(absl::StrCat("trajectory: the path runs to ", spec.trajectory.back().t_s,
                                                     " s, past the song's ", options.duration_s, " s"));
    }
    c.trajectory = spec.trajectory;
  }
  if (absl::Status s = ValidateControls(c); !s.ok()) return s;
  if (names != nullptr) *names = present;
  return c;
}

}  // namespace dance::engine
