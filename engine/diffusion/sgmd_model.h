// SGMD, the motion-diffusion editor's denoiser (docs/diffusion.md sections 3 and 7): loads a weights file
// of kind "sgmd" and predicts a window's clean motion x0 from the noised x_t, the window's music and a
// style vector. The sampler (ddim.h) and the whole-dance driver (sgmd_dance.h) are built on it.
//
// Layout (docs/engine.md): activations are column-major (features, tokens); a window's motion is
// (D, N) = (78, frames), its music input (2 (F + P), n) = one column per music token.
//
// Usage:
//   ASSIGN_OR_RETURN(std::shared_ptr<const SgmdModel> m, SgmdModel::Load("models/sgmd.dncw"));
//   SgmdModel::Context c = m->EncodeMusic(music);      // once per window
//   SgmdModel::Context none = m->NullContext();        // the dropped music (guidance)
//   Eigen::VectorXf sv = m->StyleVector(weights);      // (n_styles + 1) weights, the last "none"
//   Eigen::MatrixXf x0(m->config().pose_dim, m->config().frames);
//   m->Denoise(x_t, t, c, sv, &x0);
//
// Thread safety: the model is immutable after Load; Denoise and EncodeMusic may run concurrently on
// different outputs (they allocate their own scratch).
//
// The shapes below are preconditions: a mismatched matrix, style vector or context is a programming error
// and aborts (ABSL_RAW_CHECK), not a Status.
#ifndef DANCE_ENGINE_DIFFUSION_SGMD_MODEL_H_
#define DANCE_ENGINE_DIFFUSION_SGMD_MODEL_H_

#include <memory>
#include <string>
#include <vector>

#include "Eigen/Core"
#include "absl/status/statusor.h"
#include "engine/nn/layers.h"
#include "engine/vq/skeleton.h"

namespace dance::engine {

struct SgmdConfig {
  int feature_dim = 108;
  int pre_dim = 128;
  int pose_dim = 78;
  int frames = 150;
  int frames_per_token = 2;
  int d_model = 192;
  int n_heads = 4;
  int n_layers = 4;
  int n_music_layers = 2;
  int n_styles = 6;
  int style_dim = 64;
  float style_mod_r = 0.0f;
  int diffusion_steps = 1000;
  // What the output layer gives: x0 itself, or v (x0 = sqrt(abar_t) x_t - sqrt(1 - abar_t) v; metadata
  // sgmd.prediction "x0" (the default when absent) or "v").
  enum class Prediction { kX0, kV };
  Prediction prediction = Prediction::kX0;
  int tokens() const { return frames / frames_per_token; }
  int music_dim() const { return frames_per_token * (feature_dim + pre_dim); }
};

// The file's sampling defaults (metadata "sampling").
struct SgmdSamplingDefaults {
  int steps = 50;
  float guidance = 1.0f;
  int overlap_frames = 75;
};

class SgmdModel {
 public:
  // A window's music as the decoder reads it: the encoded tokens (d, n), their mean pooled through
  // music_pool (d), and every decoder block's cross-attention keys and values (d, n) each.
  struct Context {
    Eigen::MatrixXf tokens;
    Eigen::VectorXf pooled;
    std::vector<Eigen::MatrixXf> keys, values;
  };

  // InvalidArgument naming the problem: not kind "sgmd", a missing or misshaped tensor, bad metadata. The
  // file's own errors pass through from WeightsFile::Load (NotFound for a missing file, DataLoss, ...).
  static absl::StatusOr<std::shared_ptr<const SgmdModel>> Load(const std::string& path);

  const SgmdConfig& config() const { return config_; }
  const std::string& model_id() const { return model_id_; }
  const std::vector<std::string>& styles() const { return styles_; }
  const Skeleton& skeleton() const { return skeleton_; }
  const SgmdSamplingDefaults& sampling_defaults() const { return sampling_; }
  const Eigen::VectorXf& pose_mean() const { return pose_mean_; }
  const Eigen::VectorXf& pose_std() const { return pose_std_; }
  const Eigen::VectorXf& music_mean() const { return music_mean_; }
  const Eigen::VectorXf& music_std() const { return music_std_; }
  // abar_t, t = 0..T-1, widened to double.
  const std::vector<double>& alphas_cumprod() const { return alphas_cumprod_; }

  // music: (music_dim, n) normalised music tokens (docs/diffusion.md section 1).
  Context EncodeMusic(const Eigen::MatrixXf& music) const;
  // music_null in place of the encoded music.
  Context NullContext() const;
  // sum_i w_i style_table[i]; `weights` has n_styles + 1 entries (the last is "none").
  Eigen::VectorXf StyleVector(const Eigen::VectorXf& weights) const;
  // x0 (D, N) = the denoiser at step t (0 <= t < T) on x_t (D, N). `x0` is resized if needed.
  void Denoise(const Eigen::MatrixXf& x_t, int t, const Context& context, const Eigen::VectorXf& style_vector,
               Eigen::MatrixXf* x0) const;

  struct Impl;  // weights (sgmd_model.cc)
  ~SgmdModel();
  SgmdModel(const SgmdModel&) = delete;
  SgmdModel& operator=(const SgmdModel&) = delete;

 private:
  SgmdModel();
  SgmdConfig config_;
  std::string model_id_;
  std::vector<std::string> styles_;
  Skeleton skeleton_;
  SgmdSamplingDefaults sampling_;
  Eigen::VectorXf pose_mean_, pose_std_, music_mean_, music_std_;
  std::vector<double> alphas_cumprod_;
  std::unique_ptr<Impl> impl_;
};

}  // namespace dance::engine

#endif  // DANCE_ENGINE_DIFFUSION_SGMD_MODEL_H_
