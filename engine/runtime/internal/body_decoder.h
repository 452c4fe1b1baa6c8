// BodyDecoder: a session's codes-to-body stage. It owns both VQ decoders' causal conv histories, the root
// integrator (position and heading) and the foot lock's held feet: decoded pose features become global
// joint positions (Reconstruct), and an emitted frame's last stage is the foot lock and the joint
// rotations (Finish). docs/model.md section 7.
//
// Usage (inside StepBatch, after VqDecoder::DecodeBatch over body.upper_state() / lower_state()):
//   body.Reconstruct(upper.col(f).data(), lower.col(f).data(), &frame.positions);
//   body.Finish(frame, /*foot_lock=*/true);
//
// State: every field that changes lives in BodyState (snapshot = copy). Not thread-safe.
#ifndef DANCE_ENGINE_RUNTIME_INTERNAL_BODY_DECODER_H_
#define DANCE_ENGINE_RUNTIME_INTERNAL_BODY_DECODER_H_

#include <array>
#include <cstdint>

#include "Eigen/Core"
#include "absl/status/status.h"
#include "engine/runtime/model.h"
#include "engine/runtime/pose_frame.h"
#include "engine/vq/foot_lock.h"
#include "engine/vq/pose_reconstructor.h"
#include "engine/vq/vq_decoder.h"

namespace dance::engine {

struct BodyState {
  VqDecoderState upper, lower;  // the decoders' conv histories
  PoseState pose;               // the integrated root
  FootLockState foot_lock;      // carried over emitted (real-time) frames
};

class BodyDecoder {
 public:
  explicit BodyDecoder(const Model& model);

  VqDecoderState* upper_state() { return &state_.upper; }
  VqDecoderState* lower_state() { return &state_.lower; }
  // One decoded frame ((45) upper and (31) lower features) to global positions, integrating the root.
  void Reconstruct(const float* upper, const float* lower, std::array<Eigen::Vector3f, 24>* positions) {
    reconstructor_.Reconstruct(upper, lower, state_.pose, positions, nullptr);
  }
  // An emitted frame's last stage: the foot lock (if on) on its projected positions, then its rotations.
  void Finish(PoseFrame& frame, bool foot_lock);
  // The body's heading now (radians about +Y; 0 faces +Z).
  double yaw() const { return state_.pose.yaw; }
  const BodyState& state() const { return state_; }

  // InvalidArgument ("snapshot is from a different model") unless the decoder histories fit this model.
  absl::Status Validate(const BodyState& state) const;
  void Restore(const BodyState& state) { state_ = state; }
  void Reset();
  int64_t Bytes() const { return state_.upper.Bytes() + state_.lower.Bytes(); }

 private:
  const Model* model_;
  PoseReconstructor reconstructor_;
  FootLock foot_lock_;
  BodyState state_;
};

}  // namespace dance::engine

#endif  // DANCE_ENGINE_RUNTIME_INTERNAL_BODY_DECODER_H_
