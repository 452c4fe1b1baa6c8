// PMMM block of one stream: style modulation, x += Mamba(RMSNorm_1(x)), x += GatedMLP(RMSNorm_2(x)),
// with Mamba v1 run one token at a time from its recurrent state (docs/model.md section 5,
// training/model/mamba.py `step`).
//
// One call advances L lanes by one token of this block's stream: x is (d, L); projections are GEMMs over
// the L lanes, the depthwise conv and selective scan run per lane on its state.
//
// Thread safety: immutable after Load; Step mutates only the lanes' states and the workspace.
#ifndef DANCE_ENGINE_MODEL_PMMM_BLOCK_H_
#define DANCE_ENGINE_MODEL_PMMM_BLOCK_H_

#include <string>

#include "absl/types/span.h"
#include "engine/model/seq_config.h"
#include "engine/model/sequence_state.h"
#include "engine/model/style_modulation.h"
#include "engine/model/workspace.h"
#include "engine/nn/layers.h"

namespace dance::engine {

class PmmmBlock {
 public:
  // Loads the tensors under `prefix` (e.g. "seq.pmmm.0.1").
  static absl::StatusOr<PmmmBlock> Load(const WeightsFile& file, const std::string& prefix, const SeqConfig& c);

  const StyleModulationWeights& style() const { return style_; }

  // x: (d, L) this stream's tokens, updated in place. `state` indexes SequenceState::conv/ssm,
  // `style_block` SequenceState::style_bias.
  void Step(ColsRef x, absl::Span<SequenceState* const> lanes, int state, int style_block, Workspace& ws) const;

 private:
  SeqConfig c_;
  StyleModulationWeights style_;
  Eigen::VectorXf norm1_;    // (d)
  Eigen::VectorXf norm2_;    // (d)
  RowMatrix in_proj_;        // (2 d_inner, d)
  Eigen::MatrixXf conv_w_;   // (d_inner, d_conv), column j multiplies input t - (d_conv - 1) + j
  Eigen::VectorXf conv_b_;   // (d_inner)
  RowMatrix x_proj_;         // (dt_rank + 2 d_state, d_inner)
  RowMatrix dt_proj_;        // (d_inner, dt_rank)
  Eigen::VectorXf dt_bias_;  // (d_inner)
  Eigen::MatrixXf neg_a_;    // (d_inner, d_state) = -exp(A_log)
  Eigen::VectorXf d_skip_;   // (d_inner) D
  RowMatrix out_proj_;       // (d, d_inner)
  GatedMlp mlp_;
};

}  // namespace dance::engine

#endif  // DANCE_ENGINE_MODEL_PMMM_BLOCK_H_
