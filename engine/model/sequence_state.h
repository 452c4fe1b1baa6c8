// Per-stream state of the sequence model (one "lane"): KV caches of the TGCA blocks, Mamba conv and SSM
// states of the PMMM blocks, the step counter and the style modulation biases.
//
// Sized once by SequenceModel::NewState and never resized, so stepping does not allocate. Copyable: a copy
// is a snapshot (Session snapshot/restore copies it). Bytes() is its memory footprint.
//
// Thread safety: none; owned by one Session (one owner at a time).
#ifndef DANCE_ENGINE_MODEL_SEQUENCE_STATE_H_
#define DANCE_ENGINE_MODEL_SEQUENCE_STATE_H_

#include <cstdint>
#include <vector>

#include "Eigen/Core"

namespace dance::engine {

struct SequenceState {
  int64_t step = 0;  // code steps taken so far (the next step's index t)
  // Per TGCA layer (n_base base blocks, then the final block): ring buffers over the last W steps,
  // (d, 3W); step t' stream s lives in column 3 * (t' mod W) + s.
  std::vector<Eigen::MatrixXf> keys;
  std::vector<Eigen::MatrixXf> values;
  // Per PMMM layer and stream (index layer * 3 + stream): the last d_conv - 1 conv inputs, oldest first,
  // (d_inner, d_conv - 1), and the selective-scan state hs, (d_inner, d_state).
  std::vector<Eigen::MatrixXf> conv;
  std::vector<Eigen::MatrixXf> ssm;
  // Style modulation additive factors W_sm sv + b_sm of every block, (d, n_style_blocks); see
  // SequenceModel::StyleBlockIndex.
  Eigen::MatrixXf style_bias;

  // Zeroes caches and states and the step counter; keeps the style.
  void ClearHistory() {
    step = 0;
    for (auto* group : {&keys, &values, &conv, &ssm}) {
      for (Eigen::MatrixXf& m : *group) m.setZero();
    }
  }

  int64_t Bytes() const {
    int64_t n = style_bias.size();
    for (const auto* group : {&keys, &values, &conv, &ssm}) {
      for (const Eigen::MatrixXf& m : *group) n += m.size();
    }
    return n * static_cast<int64_t>(sizeof(float)) + static_cast<int64_t>(sizeof(*this));
  }
};

}  // namespace dance::engine

#endif  // DANCE_ENGINE_MODEL_SEQUENCE_STATE_H_
