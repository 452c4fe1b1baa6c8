#include "engine/model/seq_config.h"

#include <cmath>
#include <string>

#include "absl/status/status.h"
#include "absl/strings/str_cat.h"
#include "engine/nn/weights_file.h"

namespace dance::engine {
namespace {

bool ReadBool(const nlohmann::json& hp, const char* key, bool fallback) {
  return hp.contains(key) && hp[key].is_boolean() ? hp[key].get<bool>() : fallback;
}

}  // namespace

absl::StatusOr<SeqConfig> SeqConfig::FromMetadata(const nlohmann::json& metadata) {
  if (!metadata.contains("hyperparameters") || !metadata["hyperparameters"].is_object()) {
    return absl::InvalidArgumentError("weights metadata: no \"hyperparameters\" object");
  }
  const nlohmann::json& hp = metadata["hyperparameters"];
  SeqConfig c;
  struct Field {
    const char* key;
    int* out;
    int lo, hi;
  };
  const Field fields[] = {
      {"feature_dim", &c.feature_dim, 1, 4096},     {"pre_dim", &c.pre_dim, 0, 4096},
      {"frames_per_step", &c.frames_per_step, 4, 4}, {"codebook_size", &c.codebook_size, 2, 1 << 16},
      {"d_model", &c.d_model, 1, 8192},             {"n_heads", &c.n_heads, 1, 256},
      {"n_base", &c.n_base, 0, 64},                 {"n_head", &c.n_head, 0, 64},
      {"attn_window", &c.attn_window, 1, 4096},     {"d_state", &c.d_state, 1, 1024},
      {"d_conv", &c.d_conv, 1, 64},                 {"expand", &c.expand, 1, 16},
      {"n_styles", &c.n_styles, 0, 1024},           {"style_dim", &c.style_dim, 1, 4096},
      {"music_lookahead_steps", &c.music_lookahead_steps, 0, 8},
  };
  for (const Field& f : fields) {
    if (absl::Status s = ReadMetadataInt(hp, "hyperparameters", f.key, f.lo, f.hi, f.out); !s.ok()) return s;
  }
  if (!hp.contains("style_mod_r") || !hp["style_mod_r"].is_number()) {
    return absl::InvalidArgumentError("weights metadata: hyperparameters.style_mod_r missing");
  }
  c.style_mod_r = hp["style_mod_r"].get<float>();
  if (!(c.style_mod_r > 0.0f) || !std::isfinite(c.style_mod_r)) {
    return absl::InvalidArgumentError("weights metadata: hyperparameters.style_mod_r must be > 0");
  }
  c.use_pre = ReadBool(hp, "use_pre", true);
  c.use_gate = ReadBool(hp, "use_gate", true);
  c.shared_mamba = ReadBool(hp, "shared_mamba", false);
  if (c.d_model % c.n_heads != 0) {
    return absl::InvalidArgumentError(
        absl::StrCat("weights metadata: d_model ", c.d_model, " not divisible by n_heads ", c.n_heads));
  }
  return c;
}

}  // namespace dance::engine
