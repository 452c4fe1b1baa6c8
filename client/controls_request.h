// The controls a client sends (dance.v1.MotionControls, Control.steer), from the files and flags a user
// gives: motion files go as they are (the server reads dance-motion/v1 JSON and BVH), a dance-trajectory/v1
// path and a dance-mask/v1 mask become their messages. docs/controls.md has the formats.
//
// Usage:
//   ControlFiles f{.seed_motion = "seed.json", .trajectory = "path.json"};
//   ASSIGN_OR_RETURN(dance::v1::MotionControls c, ControlsFromFiles(f));
//   *header.mutable_controls() = c;
//   ASSIGN_OR_RETURN(TimedControl steer, ParseSteerFlag("2:5:1.5:0"));   // at 2 s: be at (1.5, 0) at 5 s
//
// Errors: NotFound (a file), InvalidArgument naming the file and what is wrong. Thread safety: pure.
#ifndef DANCE_CLIENT_CONTROLS_REQUEST_H_
#define DANCE_CLIENT_CONTROLS_REQUEST_H_

#include <string>

#include "absl/status/statusor.h"
#include "dance/v1/dance.pb.h"

namespace dance::client {

struct ControlFiles {
  std::string seed_motion, given_upper, given_lower, keyframes, inpaint, mask, trajectory;
  bool empty() const {
    return seed_motion.empty() && given_upper.empty() && given_lower.empty() && keyframes.empty() &&
           inpaint.empty() && mask.empty() && trajectory.empty();
  }
};

absl::StatusOr<dance::v1::MotionControls> ControlsFromFiles(const ControlFiles& files);

// A Control to send once the audio sent reaches `at_s` seconds.
struct TimedControl {
  double at_s = 0.0;
  dance::v1::Control control;
};

// "AT:T:X:Z": once the audio reaches AT s, steer to be at (X, Z) m at T s.
absl::StatusOr<TimedControl> ParseSteerFlag(const std::string& text);
// "AT:FILE": once the audio reaches AT s, hand the dance over to the clip FILE (a seed from the next frame).
absl::StatusOr<TimedControl> ParseHandoverFlag(const std::string& text);

}  // namespace dance::client

#endif  // DANCE_CLIENT_CONTROLS_REQUEST_H_
