// TGCA block: gated cross-conditional causal attention over the three interleaved streams, with a
// sliding-window KV cache and ALiBi (docs/model.md section 5, training/model/tgca.py `step`).
//
//   x = StyleMod(x); h = RMSNorm_1(x); z = SiLU(W_in h); q, k, v = W_q z, W_k z, W_v z
//   a = softmax(q k^T / sqrt(d_head) - slope_h (t - t')) v   over steps t - W < t' <= t, all streams
//   x += W_o (a * SiLU(W_g h));   x += GatedMLP(RMSNorm_2(x))
//
// One call advances L lanes by one step: x is (d, 3L), tokens (music, upper, lower) of lane b in columns
// 3b..3b+2; every projection is one GEMM over all 3L tokens.
//
// Thread safety: immutable after Load; Step mutates only the lanes' states and the workspace.
#ifndef DANCE_ENGINE_MODEL_TGCA_BLOCK_H_
#define DANCE_ENGINE_MODEL_TGCA_BLOCK_H_

#include <map>
#include <string>
#include <vector>

#include "absl/types/span.h"
#include "engine/model/seq_config.h"
#include "engine/model/sequence_state.h"
#include "engine/model/style_modulation.h"
#include "engine/model/workspace.h"
#include "engine/nn/layers.h"

namespace dance::engine {

// Optional per-step record of intermediate activations for golden tests: name -> (d, 3L).
using Trace = std::map<std::string, Eigen::MatrixXf>;

class TgcaBlock {
 public:
  // Loads the tensors under `prefix` (e.g. "seq.base.0").
  static absl::StatusOr<TgcaBlock> Load(const WeightsFile& file, const std::string& prefix, const SeqConfig& c);

  const StyleModulationWeights& style() const { return style_; }

  // Advances lanes by one step. `cache` is this block's index into SequenceState::keys/values,
  // `style_block` its column of SequenceState::style_bias. `trace`, if not null, receives
  // "<name>.attn_out".
  void Step(absl::Span<SequenceState* const> lanes, int cache, int style_block, Workspace& ws, Trace* trace,
            const std::string& name) const;

 private:
  void Attend(SequenceState& lane, int cache, int lane_index, Workspace& ws) const;

  SeqConfig c_;
  std::vector<float> slopes_;     // (n_heads) ALiBi slopes
  StyleModulationWeights style_;
  Eigen::VectorXf norm1_;         // (d)
  Eigen::VectorXf norm2_;         // (d)
  RowMatrix w_in_g_;              // (2d, d): rows [W_in; W_g]
  RowMatrix w_qkv_;               // (3d, d): rows [W_q; W_k; W_v]
  RowMatrix w_o_;                 // (d, d)
  GatedMlp mlp_;
};

}  // namespace dance::engine

#endif  // DANCE_ENGINE_MODEL_TGCA_BLOCK_H_
