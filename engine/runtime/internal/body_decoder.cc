#include "engine/runtime/internal/body_decoder.h"

namespace dance::engine {

BodyDecoder::BodyDecoder(const Model& model)
    : model_(&model), reconstructor_(model.skeleton()), foot_lock_(model.skeleton()) {
  Reset();
}

void BodyDecoder::Finish(PoseFrame& frame, bool foot_lock) {
  if (foot_lock) {
    foot_lock_.Apply(state_.foot_lock, &frame.positions);
  } else {
    // Turned off mid-stream (Session::SetSampling; the server never does), a held foot returns to its
    // decoded place at once; turned back on, the lock starts from the feet where they are.
    state_.foot_lock = FootLockState();
  }
  reconstructor_.JointRotations(frame.positions, &frame.rotations);
}

absl::Status BodyDecoder::Validate(const BodyState& s) const {
  if (s.upper.history.size() != state_.upper.history.size() || s.lower.history.size() != state_.lower.history.size()) {
    return absl::InvalidArgumentError("session restore: snapshot is from a different model");
  }
  return absl::OkStatus();
}

void BodyDecoder::Reset() {
  state_ = BodyState();
  state_.upper = model_->upper_decoder().NewState();
  state_.lower = model_->lower_decoder().NewState();
}

}  // namespace dance::engine
