// The streaming Danceba sequence model (docs/model.md sections 2-6): embeddings, n_base TGCA blocks,
// n_head PMMM blocks (per stream), the final TGCA block, RMSNorm and the two heads.
//
// Weights are immutable after Load and shared by every session; each stream's state is a SequenceState
// ("lane"). Step advances any number of lanes by one code step with one pass over the weights: every
// Linear is a matrix-matrix product over the batch.
//
// Usage:
//   absl::StatusOr<SequenceModel> model = SequenceModel::Load(weights);
//   SequenceState state = model->NewState();
//   Workspace ws; ws.Reserve(model->config(), 1);
//   LaneInput in{music_4f, pre_p, /*upper=*/K, /*lower=*/K, &state};   // BOS at step 0
//   model->Step({&in, 1}, ws);   // logits in ws.logits_u.col(0), ws.logits_l.col(0)
//
// Thread safety: Load'ed model is read-only and safe to share; Step mutates only the given lanes' states
// and the workspace, so distinct threads need distinct workspaces and lanes.
#ifndef DANCE_ENGINE_MODEL_SEQUENCE_MODEL_H_
#define DANCE_ENGINE_MODEL_SEQUENCE_MODEL_H_

#include <string>
#include <utility>
#include <vector>

#include "absl/status/statusor.h"
#include "absl/types/span.h"
#include "engine/model/pmmm_block.h"
#include "engine/model/seq_config.h"
#include "engine/model/sequence_state.h"
#include "engine/model/tgca_block.h"
#include "engine/model/workspace.h"
#include "engine/nn/layers.h"
#include "engine/nn/weights_file.h"

namespace dance::engine {

// One lane's inputs for a step. Pointers must stay valid for the call.
struct LaneInput {
  const float* music = nullptr;  // (4F) raw (unnormalised) features of the step's 4 frames, frame-major
  const float* pre = nullptr;    // (P) PRE of the step's last frame
  int upper_code = 0;            // u_t in [0, K]; K = BOS
  int lower_code = 0;            // l_t in [0, K]
  SequenceState* state = nullptr;
};

class SequenceModel {
 public:
  // Reads metadata "hyperparameters" and every tensor under "seq." (docs/weights-format.md).
  static absl::StatusOr<SequenceModel> Load(const WeightsFile& file);

  const SeqConfig& config() const { return c_; }

  // A fresh lane at step 0 with style "none".
  SequenceState NewState() const;
  // Style vector sum_i w_i E_style[i]; `weights` are (row, weight) pairs with row n_styles = "none".
  Eigen::VectorXf StyleVector(absl::Span<const std::pair<int, float>> weights) const;
  // Recomputes the lane's style modulation factors for style vector `sv` (d_s).
  void SetStyle(const Eigen::VectorXf& sv, SequenceState* state) const;

  // Advances every lane by one step; lane b's logits land in ws.logits_u.col(b) / ws.logits_l.col(b)
  // (K each). Reserves the workspace if it is too small (the only allocation). `trace`, if not null,
  // receives the named intermediate activations of training/model/danceba.py (each (d, 3L)).
  void Step(absl::Span<const LaneInput> lanes, Workspace& ws, Trace* trace = nullptr) const;

  // The training data's mean raw music token (4F): what a lane reads in place of the song's music for music
  // guidance (the model learned it with --music-dropout; SamplingOptions::music_guidance).
  const Eigen::VectorXf& music_mean() const { return music_mean_; }

  int num_style_blocks() const { return c_.n_base + c_.n_head * c_.n_pmmm_sets() + 1; }

 private:
  SeqConfig c_;
  Eigen::VectorXf music_mean_;   // (4F)
  Eigen::VectorXf music_std_;    // (4F)
  RowMatrix w_music_;            // (d, 4F)
  Eigen::VectorXf b_music_;      // (d)
  RowMatrix embed_upper_;        // (K + 1, d)
  RowMatrix embed_lower_;        // (K + 1, d)
  RowMatrix embed_stream_;       // (3, d)
  RowMatrix w_pre_;              // (d, P)
  Eigen::VectorXf b_pre_;        // (d)
  Eigen::VectorXf bn_scale_;     // (d)
  Eigen::VectorXf bn_shift_;     // (d)
  RowMatrix style_table_;        // (n_styles + 1, d_s)
  std::vector<TgcaBlock> base_;  // n_base
  std::vector<PmmmBlock> pmmm_;  // n_head * n_pmmm_sets, index layer * sets + stream
  std::vector<TgcaBlock> final_; // exactly one (vector: TgcaBlock has no default constructor use)
  Eigen::VectorXf norm_f_;       // (d)
  RowMatrix head_upper_;         // (K, d)
  RowMatrix head_lower_;         // (K, d)
};

}  // namespace dance::engine

#endif  // DANCE_ENGINE_MODEL_SEQUENCE_MODEL_H_
