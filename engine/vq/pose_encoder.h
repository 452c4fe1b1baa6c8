// PoseEncoder: given motion (global joint positions) to the pose codes the VQ-VAE would give it: the pose
// representation of docs/model.md section 7 (the exact inverse of PoseReconstructor's root integration;
// Python reference training/data/representation.py `encode`), normalised, through the VQ-VAE encoder of
// one body part (the op list `vq.<part>.encoder_ops` of the weights file: convolutions with symmetric
// padding and stride, so it looks ahead: offline only), then the nearest codebook row. The controls
// (seed motion, a given half, keyframes, inpainting) use it to turn motion into codes the model and the
// decoders can be forced with.
//
// Usage:
//   absl::StatusOr<VqEncoder> enc = VqEncoder::Load(weights, "upper", decoder.codebook());
//   PoseFeatures f = EncodePoseFeatures(positions);          // (45, T) upper, (31, T) lower
//   std::vector<int> codes = enc->Encode(f.upper);            // T / 4 codes (T padded to a multiple of 4)
//
// Thread safety: immutable after Load; Encode allocates (it is for whole clips, not the hot path).
#ifndef DANCE_ENGINE_VQ_POSE_ENCODER_H_
#define DANCE_ENGINE_VQ_POSE_ENCODER_H_

#include <array>
#include <string>
#include <vector>

#include "Eigen/Core"
#include "absl/status/statusor.h"
#include "engine/nn/layers.h"
#include "engine/nn/weights_file.h"
#include "engine/vq/skeleton.h"

namespace dance::engine {

using JointPositions = std::array<Eigen::Vector3f, kNumJoints>;

struct PoseFeatures {
  Eigen::MatrixXf upper;  // (45, T): 15 upper joints relative to the pelvis in the facing frame
  Eigen::MatrixXf lower;  // (31, T): 9 lower joints (pelvis row (0, h, 0)), then vx, vz, yaw rate, height
  std::vector<double> yaw;     // (T) facing yaw of each frame, radians (0 faces +Z)
  std::vector<Eigen::Vector2d> root_xz;  // (T) the pelvis on the floor, metres
};

// An angle wrapped to (-pi, pi] (the pose representation's yaw rate; training/data/representation.py).
double WrapAngle(double a);

// The facing yaw of a pose: forward = across x up, across = (left_hip - right_hip) + (left_shoulder -
// right_shoulder); 0 faces +Z.
double FacingYaw(const JointPositions& positions);

// positions (T frames) -> features; frame 0's root velocity and yaw rate are 0.
PoseFeatures EncodePoseFeatures(const std::vector<JointPositions>& positions);

class VqEncoder {
 public:
  // Loads part `part`'s encoder ops and their tensors, with the part's codebook (K, code_dim).
  // InvalidArgument / NotFound if the file has no encoder_ops (older files) or they are malformed.
  static absl::StatusOr<VqEncoder> Load(const WeightsFile& file, const std::string& part, const RowMatrix& codebook);

  // Denormalised features (in_dim, T), T >= 1 -> one code per 4 frames (the last frame is repeated up to a
  // multiple of 4), each the nearest codebook row (lowest index of equals) to the encoder's output.
  std::vector<int> Encode(const Eigen::MatrixXf& features) const;
  int in_dim() const { return in_dim_; }
  int downsample() const { return downsample_; }
  // An upper bound on how many frames after a code's first frame its code depends on (the convolutions'
  // forward reach, the code's own frames, one frame of velocity): a live given motion settles into codes
  // this many frames behind the newest pose.
  int lookahead_frames() const { return lookahead_frames_ + downsample_ + 1; }

 private:
  enum class OpKind { kConv, kRelu, kResBegin, kResEnd };
  struct Conv {
    std::vector<Eigen::MatrixXf> taps;  // k x (out, in)
    Eigen::VectorXf bias;               // (out)
    int dilation = 1, stride = 1, pad = 0;
  };
  struct Op {
    OpKind kind;
    int conv = -1;
  };

  std::vector<Op> ops_;
  std::vector<Conv> convs_;
  RowMatrix codebook_;          // (K, code_dim)
  Eigen::VectorXf code_norms_;  // (K) squared norms
  Eigen::VectorXf pose_mean_, pose_std_;  // (in_dim)
  int in_dim_ = 0;
  int downsample_ = 1;
  int lookahead_frames_ = 0;  // the convolutions' forward reach, frames
};

}  // namespace dance::engine

#endif  // DANCE_ENGINE_VQ_POSE_ENCODER_H_
