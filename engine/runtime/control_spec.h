// ControlSpec: the controls as a request states them (files' text or poses, mask spans, a floor path),
// and BuildControls, which turns them into the engine's Controls (controls.h). The one place where
// dance-generate's flags, the server's stream headers and Control messages, and tests become a session's
// controls, so every form is read and checked the same way.
//
// Usage:
//   ControlSpec spec;
//   spec.seed = {.name = "seed.json", .text = *ReadTextFile("seed.json")};
//   spec.trajectory = *ReadTrajectoryFile("path.json");
//   ASSIGN_OR_RETURN(Controls c, BuildControls(spec, {.duration_s = song_s}));
//
// Placement: a motion given as text is placed by its own audio_offset_s (dance-motion/v1) or at 0 (BVH),
// then moved by start_s; a motion given as poses starts at start_s (30 fps) or, for keyframes, at its
// times_s. Combination: later wins where two give the same joint, in the order inpaint, given halves, seed,
// keyframes.
//
// Errors: InvalidArgument naming the control and what is wrong (motion_io.h's readers' errors, a seed
// shorter than 4 frames, keyframes without times, a mask without its dance, motion that starts after the
// song, a path that runs past it). Thread safety: pure functions.
#ifndef DANCE_ENGINE_RUNTIME_CONTROL_SPEC_H_
#define DANCE_ENGINE_RUNTIME_CONTROL_SPEC_H_

#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "engine/runtime/controls.h"
#include "engine/runtime/motion_io.h"

namespace dance::engine {

// Given motion: the text of a motion file, or poses.
struct MotionSource {
  std::string name;                       // what errors call it (a path, or the field's name)
  std::string text;                       // dance-motion/v1 JSON or BVH text; or, if empty:
  std::vector<JointPositions> positions;  // poses, 30 fps from start_s, or at times_s
  double start_s = 0.0;                   // audio time of the first pose (added to a file's own offset)
  std::vector<double> times_s;            // poses only: each pose's audio time (keyframes)
  bool empty() const { return text.empty() && positions.empty(); }
};

struct ControlSpec {
  MotionSource inpaint;                 // a recorded dance; what inpaint_known does not list is re-danced
  std::vector<MaskSpan> inpaint_known;
  std::string mask_name = "mask";       // what errors call the mask
  MotionSource given_upper, given_lower;
  MotionSource seed;                    // >= 4 frames
  MotionSource keyframes;               // text with "times_s", or poses with times_s
  std::vector<TrajectoryPoint> trajectory;  // empty = none (>= 2 points otherwise)
  bool empty() const {
    return inpaint.empty() && given_upper.empty() && given_lower.empty() && seed.empty() && keyframes.empty() &&
           trajectory.empty();
  }
};

struct BuildOptions {
  // The song's length: motion must start within it, a path may run at most 1 s past it (infinite: live).
  double duration_s = std::numeric_limits<double>::infinity();
  // A seed that would start before this audio frame starts at it instead (a hand-over mid-stream: the
  // clip plays from the next frame the session emits).
  int64_t seed_not_before_frame = 0;
};

// `names` (may be null) receives the controls present, in the order above ("inpaint", "given_upper", ...).
absl::StatusOr<Controls> BuildControls(const ControlSpec& spec, const BuildOptions& options,
                                       std::vector<std::string>* names = nullptr);

}  // namespace dance::engine

#endif  // DANCE_ENGINE_RUNTIME_CONTROL_SPEC_H_
