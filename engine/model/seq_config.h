// Sizes of the streaming sequence model, read from the weights file's metadata "hyperparameters"
// (written by training/model/config.py SeqConfig.to_dict; math in docs/model.md sections 2-5).
//
// Usage:
//   absl::StatusOr<SeqConfig> cfg = SeqConfig::FromMetadata(weights.metadata());
//
// Thread safety: a plain value.
#ifndef DANCE_ENGINE_MODEL_SEQ_CONFIG_H_
#define DANCE_ENGINE_MODEL_SEQ_CONFIG_H_

#include "absl/status/statusor.h"
#include "nlohmann/json.hpp"

namespace dance::engine {

struct SeqConfig {
  int feature_dim = 0;       // F, music feature dims per frame
  int pre_dim = 0;           // P, PRE dims per frame
  int frames_per_step = 4;
  int codebook_size = 0;     // K; index K is BOS
  int d_model = 0;           // d
  int n_heads = 0;
  int n_base = 0;            // TGCA blocks before PMMM
  int n_head = 0;            // PMMM blocks
  int attn_window = 0;       // W, steps
  int d_state = 0;
  int d_conv = 0;
  int expand = 0;
  int n_styles = 0;          // style rows excluding "none" (row n_styles)
  int style_dim = 0;         // d_s
  float style_mod_r = 0.0f;  // r
  int music_lookahead_steps = 0;
  bool use_pre = true;
  bool use_gate = true;
  bool shared_mamba = false;

  int d_inner() const { return expand * d_model; }
  int dt_rank() const { return (d_model + 15) / 16; }
  int d_ff() const { return 2 * d_model; }
  int d_head() const { return d_model / n_heads; }
  int music_dim() const { return frames_per_step * feature_dim; }
  int n_pmmm_sets() const { return shared_mamba ? 1 : 3; }

  // Parses metadata["hyperparameters"]; InvalidArgument on a missing key or inconsistent sizes.
  static absl::StatusOr<SeqConfig> FromMetadata(const nlohmann::json& metadata);
};

}  // namespace dance::engine

#endif  // DANCE_ENGINE_MODEL_SEQ_CONFIG_H_
