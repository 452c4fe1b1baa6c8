#include "engine/diffusion/sgmd_model.h"

#include <cmath>
#include <utility>

#include "absl/base/internal/raw_logging.h"
#include "absl/status/status.h"
#include "absl/strings/str_cat.h"
#include "engine/diffusion/motion_vector.h"
#include "engine/nn/status_macros.h"
#include "engine/nn/weights_file.h"
#include "unsupported/Eigen/SpecialFunctions"

namespace dance::engine {
namespace {

constexpr float kLayerNormEps = 1e-5f;  // torch.nn.LayerNorm's default
constexpr float kStyleModEps = 1e-6f;   // x / (||x|| r + 1e-6)
constexpr char kPrefix[] = "sgmd.";

// y = W x + b over all columns.
struct Linear {
  RowMatrix w;        // (out, in)
  Eigen::VectorXf b;  // (out)

  void Apply(const ConstColsRef& x, ColsRef out) const {
    MatMul(w, x, out);
    out.colwise() += b;
  }
};

// torch.nn.LayerNorm over the rows of each column (biased variance, eps 1e-5).
struct LayerNorm {
  Eigen::VectorXf weight;  // (d)
  Eigen::VectorXf bias;    // (d)

  // `out` may alias `x`.
  void Apply(const ConstColsRef& x, ColsRef out) const {
    const Eigen::Index d = x.rows();
    for (Eigen::Index j = 0; j < x.cols(); ++j) {
      // The moments in double (closer to torch's float32 reduction than a plain float sum); the scaling in float.
      const auto col = x.col(j).cast<double>().array();
      const double mean = col.sum() / static_cast<double>(d);
      const double var = (col - mean).square().sum() / static_cast<double>(d);
      const float mean_f = static_cast<float>(mean);
      const float rstd = static_cast<float>(1.0 / std::sqrt(var + kLayerNormEps));
      out.col(j).array() = (x.col(j).array() - mean_f) * rstd * weight.array() + bias.array();
    }
  }
};

// GELU, the exact erf form as torch computes it: x * 0.5 * (1 + erf(x / sqrt 2)), in place. Eigen's vectorised
// float erf (a rational approximation) is within 3.7e-7 of erf on [-6, 6], ~6 ulp; scalar std::erf would cost
// more than the block's GEMMs leave room for and buys nothing at the golden tolerance.
void GeluInPlace(ColsRef x) {
  auto a = x.array();
  a = a * 0.5f * (1.0f + (a * static_cast<float>(M_SQRT1_2)).erf());
}

// Multi-head attention without a mask: out (d, nq) = heads of softmax(k_h^T q_h / sqrt(d_h)) applied to v_h,
// concatenated. q (d, nq); k, v (d, m); scores (m, nq) scratch. One GEMM per head for the scores and one for
// the values.
void Attend(const ConstColsRef& q, const ConstColsRef& k, const ConstColsRef& v, int n_heads, Eigen::MatrixXf& scores,
            ColsRef out) {
  const int dh = static_cast<int>(q.rows()) / n_heads;
  const float sqrt_dh = std::sqrt(static_cast<float>(dh));
  for (int head = 0; head < n_heads; ++head) {
    const int r0 = head * dh;
    scores.noalias() = k.middleRows(r0, dh).transpose() * q.middleRows(r0, dh);
    scores /= sqrt_dh;
    for (Eigen::Index j = 0; j < scores.cols(); ++j) {
      auto col = scores.col(j).array();
      col = (col - col.maxCoeff()).exp();
      col /= col.sum();
    }
    out.middleRows(r0, dh).noalias() = v.middleRows(r0, dh) * scores;
  }
}

// torch's timestep_embedding in float32: f_i = exp(-ln(10000) i / (d/2)) with the product and quotient rounded
// to float as torch does, then sin(t f_i), cos(t f_i) of the float product. The argument reaches ~1000, where
// a float ulp is 6e-5, so it is formed exactly as the reference forms it. One difference remains: torch's
// vectorised exp (Sleef, 1 ulp) and std::exp disagree by 1 ulp on 12 of the 96 frequencies at d = 192;
// measured on a random model of the shipped size, the denoiser still matches within 1.6e-6 at t = 1..999.
void TimestepEmbedding(int t, Eigen::VectorXf& out) {
  const int half = static_cast<int>(out.size()) / 2;
  const float neg_log = static_cast<float>(-std::log(10000.0));
  const float tf = static_cast<float>(t);
  for (int i = 0; i < half; ++i) {
    const float freq = std::exp(static_cast<float>(i) * neg_log / static_cast<float>(half));
    const float a = tf * freq;
    out(i) = std::sin(a);
    out(half + i) = std::cos(a);
  }
}

// Loading: every tensor under "sgmd." with its exact shape; a missing one is InvalidArgument too (the file
// itself was readable, it is just not a complete SGMD model).
absl::Status Invalid(const absl::Status& s) {
  return absl::IsNotFound(s) ? absl::InvalidArgumentError(s.message()) : s;
}

absl::Status ReadMatrix(const WeightsFile& f, const std::string& name, int64_t rows, int64_t cols, RowMatrix* out) {
  absl::StatusOr<RowMatrix> m = LoadMatrix(f, kPrefix + name, rows, cols);
  if (!m.ok()) return Invalid(m.status());
  *out = *std::move(m);
  return absl::OkStatus();
}

absl::Status ReadVector(const WeightsFile& f, const std::string& name, int64_t n, Eigen::VectorXf* out) {
  absl::StatusOr<Eigen::VectorXf> v = LoadVector(f, kPrefix + name, n);
  if (!v.ok()) return Invalid(v.status());
  *out = *std::move(v);
  return absl::OkStatus();
}

absl::Status ReadLinear(const WeightsFile& f, const std::string& name, int64_t out, int64_t in, Linear* l) {
  DANCE_RETURN_IF_ERROR(ReadMatrix(f, name + ".weight", out, in, &l->w));
  return ReadVector(f, name + ".bias", out, &l->b);
}

// Linears with the same input stacked into one (sum of outs, in): one GEMM for q, k and v.
absl::Status ReadStacked(const WeightsFile& f, const std::string& prefix, std::initializer_list<const char*> names,
                         int64_t d, Linear* l) {
  const int64_t rows = d * static_cast<int64_t>(names.size());
  l->w.resize(rows, d);
  l->b.resize(rows);
  int64_t r0 = 0;
  for (const char* name : names) {
    Linear part;
    DANCE_RETURN_IF_ERROR(ReadLinear(f, absl::StrCat(prefix, ".", name), d, d, &part));
    l->w.middleRows(r0, d) = part.w;
    l->b.segment(r0, d) = part.b;
    r0 += d;
  }
  return absl::OkStatus();
}

absl::Status ReadLayerNorm(const WeightsFile& f, const std::string& name, int64_t d, LayerNorm* n) {
  DANCE_RETURN_IF_ERROR(ReadVector(f, name + ".weight", d, &n->weight));
  return ReadVector(f, name + ".bias", d, &n->bias);
}

// A (rows, cols) tensor read as its transpose, (cols, rows) column-major: the file's (n, d) token tables
// become (d, n) activations with the same memory.
absl::Status ReadTokens(const WeightsFile& f, const std::string& name, int64_t n, int64_t d, Eigen::MatrixXf* out) {
  RowMatrix m;
  DANCE_RETURN_IF_ERROR(ReadMatrix(f, name, n, d, &m));
  *out = m.transpose();
  return absl::OkStatus();
}

absl::StatusOr<SgmdConfig> ReadConfig(const nlohmann::json& md) {
  if (!md.contains("sgmd") || !md["sgmd"].is_object()) {
    return absl::InvalidArgumentError("weights metadata: no \"sgmd\" object (the hyperparameters)");
  }
  const nlohmann::json& hp = md["sgmd"];
  SgmdConfig c;
  struct Field {
    const char* key;
    int* out;
    int lo, hi;
  };
  const Field fields[] = {
      {"feature_dim", &c.feature_dim, 1, 4096},  {"pre_dim", &c.pre_dim, 0, 4096},
      {"pose_dim", &c.pose_dim, kMotionDims, kMotionDims},  {"frames", &c.frames, 1, 1 << 16},
      {"frames_per_token", &c.frames_per_token, 1, 1 << 16}, {"d_model", &c.d_model, 2, 8192},
      {"n_heads", &c.n_heads, 1, 256},           {"n_layers", &c.n_layers, 1, 256},
      {"n_music_layers", &c.n_music_layers, 0, 256}, {"n_styles", &c.n_styles, 0, 1024},
      {"style_dim", &c.style_dim, 1, 4096},      {"diffusion_steps", &c.diffusion_steps, 1, 1 << 20},
  };
  for (const Field& f : fields) DANCE_RETURN_IF_ERROR(ReadMetadataInt(hp, "sgmd", f.key, f.lo, f.hi, f.out));
  if (c.frames % c.frames_per_token != 0) {
    return absl::InvalidArgumentError(absl::StrCat("weights metadata: sgmd.frames ", c.frames,
                                                   " is not a multiple of frames_per_token ", c.frames_per_token));
  }
  if (c.d_model % c.n_heads != 0 || c.d_model % 2 != 0) {
    return absl::InvalidArgumentError(absl::StrCat("weights metadata: sgmd.d_model ", c.d_model,
                                                   " must be even and divisible by n_heads ", c.n_heads));
  }
  if (!hp.contains("style_mod_r") || !hp["style_mod_r"].is_number()) {
    return absl::InvalidArgumentError("weights metadata: sgmd.style_mod_r missing");
  }
  c.style_mod_r = hp["style_mod_r"].get<float>();
  if (!std::isfinite(c.style_mod_r)) return absl::InvalidArgumentError("weights metadata: sgmd.style_mod_r not finite");
  // As SGMDConfig: r <= 0 means d^-0.5 (exported files carry the resolved value).
  if (c.style_mod_r <= 0.0f) c.style_mod_r = static_cast<float>(std::pow(static_cast<double>(c.d_model), -0.5));
  if (hp.contains("prediction")) {
    const nlohmann::json& p = hp["prediction"];
    if (p == "v") {
      c.prediction = SgmdConfig::Prediction::kV;
    } else if (p != "x0") {
      return absl::InvalidArgumentError(absl::StrCat("weights metadata: sgmd.prediction must be \"x0\" or \"v\", got ",
                                                     p.dump()));
    }
  }
  return c;
}

absl::StatusOr<SgmdSamplingDefaults> ReadSampling(const nlohmann::json& md, const SgmdConfig& c) {
  SgmdSamplingDefaults s;
  s.overlap_frames = c.frames / 2;
  if (!md.contains("sampling")) return s;
  const nlohmann::json& sm = md["sampling"];
  if (!sm.is_object()) return absl::InvalidArgumentError("weights metadata: sampling must be an object");
  if (sm.contains("steps")) DANCE_RETURN_IF_ERROR(ReadMetadataInt(sm, "sampling", "steps", 1, c.diffusion_steps, &s.steps));
  if (sm.contains("overlap_frames")) {
    DANCE_RETURN_IF_ERROR(ReadMetadataInt(sm, "sampling", "overlap_frames", 0, c.frames - 1, &s.overlap_frames));
  }
  if (sm.contains("guidance")) {
    const double g = sm["guidance"].is_number() ? sm["guidance"].get<double>() : -1.0;
    if (!(g >= 0.0 && g <= 100.0)) {
      return absl::InvalidArgumentError("weights metadata: sampling.guidance must be a number in [0, 100]");
    }
    s.guidance = static_cast<float>(g);
  }
  return s;
}

}  // namespace

struct SgmdModel::Impl {
  struct EncoderBlock {
    LayerNorm norm1, norm2;
    Linear qkv;  // (3d, d): rows [W_q; W_k; W_v]
    Linear o;    // (d, d)
    Linear fc1;  // (4d, d)
    Linear fc2;  // (d, 4d)
  };
  struct DecoderBlock {
    Linear style;  // (d, d_s)
    LayerNorm norm1, norm2, norm3;
    Linear self_qkv;  // (3d, d): rows [W_q; W_k; W_v]
    Linear self_o;    // (d, d)
    Linear cross_q;   // (d, d)
    Linear cross_kv;  // (2d, d): rows [W_k; W_v], applied to the music tokens once per window
    Linear cross_o;   // (d, d)
    Linear fc1;       // (4d, d)
    Linear fc2;       // (d, 4d)
    Linear film;      // (6d, d): rows (s1, b1, s2, b2, s3, b3)
  };

  Linear motion_in;             // (d, k D)
  Eigen::MatrixXf motion_pos;   // (d, n)
  Linear music_in;              // (d, k (F + P))
  Eigen::MatrixXf music_pos;    // (d, n)
  std::vector<EncoderBlock> music_blocks;
  LayerNorm music_norm;
  Eigen::MatrixXf music_null;   // (d, n)
  Linear music_pool;            // (d, d)
  Linear time_fc1;              // (4d, d)
  Linear time_fc2;              // (d, 4d)
  RowMatrix style_table;        // (n_styles + 1, d_s)
  std::vector<DecoderBlock> blocks;
  LayerNorm norm_f;
  Linear out;                   // (k D, d)
  Context null_context;         // music_null's, computed at load
};

namespace {

// Pooled tokens and every decoder block's cross-attention keys and values.
SgmdModel::Context MakeContext(const SgmdModel::Impl& w, Eigen::MatrixXf tokens) {
  SgmdModel::Context c;
  c.tokens = std::move(tokens);
  const Eigen::Index d = c.tokens.rows(), n = c.tokens.cols();
  const Eigen::VectorXf mean = c.tokens.rowwise().mean();
  c.pooled.resize(d);
  w.music_pool.Apply(mean, c.pooled);
  Eigen::MatrixXf kv(2 * d, n);
  for (const SgmdModel::Impl::DecoderBlock& b : w.blocks) {
    b.cross_kv.Apply(c.tokens, kv);
    c.keys.push_back(kv.topRows(d));
    c.values.push_back(kv.bottomRows(d));
  }
  return c;
}

}  // namespace

SgmdModel::SgmdModel() : impl_(std::make_unique<Impl>()) {}
SgmdModel::~SgmdModel() = default;

absl::StatusOr<std::shared_ptr<const SgmdModel>> SgmdModel::Load(const std::string& path) {
  DANCE_ASSIGN_OR_RETURN(const WeightsFile file, WeightsFile::Load(path));
  const nlohmann::json& md = file.metadata();
  const std::string kind = md.contains("kind") && md["kind"].is_string() ? md["kind"].get<std::string>() : "";
  if (kind != "sgmd") {
    return absl::InvalidArgumentError(absl::StrCat("weights file '", path, "' is not an SGMD model: metadata kind ",
                                                   kind.empty() ? "missing" : "'" + kind + "'", ", expected \"sgmd\""));
  }
  std::shared_ptr<SgmdModel> m(new SgmdModel());
  DANCE_ASSIGN_OR_RETURN(m->config_, ReadConfig(md));
  const SgmdConfig& c = m->config_;
  DANCE_ASSIGN_OR_RETURN(m->sampling_, ReadSampling(md, c));
  DANCE_ASSIGN_OR_RETURN(m->skeleton_, Skeleton::FromMetadata(md));
  m->model_id_ = md.contains("model_id") && md["model_id"].is_string() ? md["model_id"].get<std::string>() : "unknown";
  if (!md.contains("styles") || !md["styles"].is_array()) {
    return absl::InvalidArgumentError("weights metadata: no \"styles\" list");
  }
  for (const nlohmann::json& s : md["styles"]) {
    if (!s.is_string()) return absl::InvalidArgumentError("weights metadata: a style name is not a string");
    m->styles_.push_back(s.get<std::string>());
  }
  if (static_cast<int>(m->styles_.size()) != c.n_styles) {
    return absl::InvalidArgumentError(absl::StrCat("weights metadata: ", m->styles_.size(), " styles, sgmd.n_styles ",
                                                   c.n_styles));
  }

  const int64_t d = c.d_model, n = c.tokens(), d_ff = 4 * d, kd = c.frames_per_token * c.pose_dim;
  Eigen::VectorXf abar;
  DANCE_RETURN_IF_ERROR(ReadVector(file, "alphas_cumprod", c.diffusion_steps, &abar));
  for (int t = 0; t < c.diffusion_steps; ++t) {
    // abar_t < 1 keeps sqrt(1 - abar_t), the sampler's divisor, away from 0.
    if (!(abar(t) >= 0.0f && abar(t) < 1.0f)) {
      return absl::InvalidArgumentError(absl::StrCat("weights file: sgmd.alphas_cumprod[", t, "] = ", abar(t),
                                                     " outside [0, 1)"));
    }
    m->alphas_cumprod_.push_back(abar(t));
  }
  DANCE_RETURN_IF_ERROR(ReadVector(file, "pose_mean", c.pose_dim, &m->pose_mean_));
  DANCE_RETURN_IF_ERROR(ReadVector(file, "pose_std", c.pose_dim, &m->pose_std_));
  DANCE_RETURN_IF_ERROR(ReadVector(file, "music_mean", c.feature_dim, &m->music_mean_));
  DANCE_RETURN_IF_ERROR(ReadVector(file, "music_std", c.feature_dim, &m->music_std_));
  if (!(m->pose_std_.minCoeff() > 0.0f) || !(m->music_std_.minCoeff() > 0.0f)) {
    return absl::InvalidArgumentError("weights file: sgmd.pose_std and sgmd.music_std must be > 0");
  }

  Impl& w = *m->impl_;
  DANCE_RETURN_IF_ERROR(ReadLinear(file, "motion_in", d, kd, &w.motion_in));
  DANCE_RETURN_IF_ERROR(ReadTokens(file, "motion_pos", n, d, &w.motion_pos));
  DANCE_RETURN_IF_ERROR(ReadLinear(file, "music_in", d, c.music_dim(), &w.music_in));
  DANCE_RETURN_IF_ERROR(ReadTokens(file, "music_pos", n, d, &w.music_pos));
  for (int i = 0; i < c.n_music_layers; ++i) {
    const std::string p = absl::StrCat("music_blocks.", i);
    Impl::EncoderBlock& b = w.music_blocks.emplace_back();
    DANCE_RETURN_IF_ERROR(ReadLayerNorm(file, p + ".norm1", d, &b.norm1));
    DANCE_RETURN_IF_ERROR(ReadLayerNorm(file, p + ".norm2", d, &b.norm2));
    DANCE_RETURN_IF_ERROR(ReadStacked(file, p + ".attn", {"q", "k", "v"}, d, &b.qkv));
    DANCE_RETURN_IF_ERROR(ReadLinear(file, p + ".attn.o", d, d, &b.o));
    DANCE_RETURN_IF_ERROR(ReadLinear(file, p + ".ffn.fc1", d_ff, d, &b.fc1));
    DANCE_RETURN_IF_ERROR(ReadLinear(file, p + ".ffn.fc2", d, d_ff, &b.fc2));
  }
  DANCE_RETURN_IF_ERROR(ReadLayerNorm(file, "music_norm", d, &w.music_norm));
  DANCE_RETURN_IF_ERROR(ReadTokens(file, "music_null", n, d, &w.music_null));
  DANCE_RETURN_IF_ERROR(ReadLinear(file, "music_pool", d, d, &w.music_pool));
  DANCE_RETURN_IF_ERROR(ReadLinear(file, "time_fc1", d_ff, d, &w.time_fc1));
  DANCE_RETURN_IF_ERROR(ReadLinear(file, "time_fc2", d, d_ff, &w.time_fc2));
  DANCE_RETURN_IF_ERROR(ReadMatrix(file, "style_table", c.n_styles + 1, c.style_dim, &w.style_table));
  for (int i = 0; i < c.n_layers; ++i) {
    const std::string p = absl::StrCat("blocks.", i);
    Impl::DecoderBlock& b = w.blocks.emplace_back();
    DANCE_RETURN_IF_ERROR(ReadLinear(file, p + ".style", d, c.style_dim, &b.style));
    DANCE_RETURN_IF_ERROR(ReadLayerNorm(file, p + ".norm1", d, &b.norm1));
    DANCE_RETURN_IF_ERROR(ReadLayerNorm(file, p + ".norm2", d, &b.norm2));
    DANCE_RETURN_IF_ERROR(ReadLayerNorm(file, p + ".norm3", d, &b.norm3));
    DANCE_RETURN_IF_ERROR(ReadStacked(file, p + ".self_attn", {"q", "k", "v"}, d, &b.self_qkv));
    DANCE_RETURN_IF_ERROR(ReadLinear(file, p + ".self_attn.o", d, d, &b.self_o));
    DANCE_RETURN_IF_ERROR(ReadLinear(file, p + ".cross_attn.q", d, d, &b.cross_q));
    DANCE_RETURN_IF_ERROR(ReadStacked(file, p + ".cross_attn", {"k", "v"}, d, &b.cross_kv));
    DANCE_RETURN_IF_ERROR(ReadLinear(file, p + ".cross_attn.o", d, d, &b.cross_o));
    DANCE_RETURN_IF_ERROR(ReadLinear(file, p + ".ffn.fc1", d_ff, d, &b.fc1));
    DANCE_RETURN_IF_ERROR(ReadLinear(file, p + ".ffn.fc2", d, d_ff, &b.fc2));
    DANCE_RETURN_IF_ERROR(ReadLinear(file, p + ".film", 6 * d, d, &b.film));
  }
  DANCE_RETURN_IF_ERROR(ReadLayerNorm(file, "norm_f", d, &w.norm_f));
  DANCE_RETURN_IF_ERROR(ReadLinear(file, "out", kd, d, &w.out));
  w.null_context = MakeContext(w, w.music_null);
  return std::shared_ptr<const SgmdModel>(std::move(m));
}

SgmdModel::Context SgmdModel::EncodeMusic(const Eigen::MatrixXf& music) const {
  const Impl& w = *impl_;
  const SgmdConfig& c = config_;
  const int d = c.d_model, n = c.tokens();
  ABSL_RAW_CHECK(music.rows() == c.music_dim() && music.cols() == n, "EncodeMusic: music must be (music_dim, n)");
  Eigen::MatrixXf x(d, n), h(d, n), qkv(3 * d, n), attn(d, n), delta(d, n), ff(4 * d, n), scores(n, n);
  w.music_in.Apply(music, x);
  x += w.music_pos;
  for (const Impl::EncoderBlock& b : w.music_blocks) {
    b.norm1.Apply(x, h);
    b.qkv.Apply(h, qkv);
    Attend(qkv.topRows(d), qkv.middleRows(d, d), qkv.bottomRows(d), c.n_heads, scores, attn);
    b.o.Apply(attn, delta);
    x += delta;
    b.norm2.Apply(x, h);
    b.fc1.Apply(h, ff);
    GeluInPlace(ff);
    b.fc2.Apply(ff, delta);
    x += delta;
  }
  w.music_norm.Apply(x, x);
  return MakeContext(w, std::move(x));
}

SgmdModel::Context SgmdModel::NullContext() const { return impl_->null_context; }

Eigen::VectorXf SgmdModel::StyleVector(const Eigen::VectorXf& weights) const {
  ABSL_RAW_CHECK(weights.size() == config_.n_styles + 1, "StyleVector: one weight per style, then \"none\"");
  return impl_->style_table.transpose() * weights;
}

void SgmdModel::Denoise(const Eigen::MatrixXf& x_t, int t, const Context& context, const Eigen::VectorXf& style_vector,
                        Eigen::MatrixXf* x0) const {
  const Impl& w = *impl_;
  const SgmdConfig& c = config_;
  const int d = c.d_model, n = c.tokens(), kd = c.frames_per_token * c.pose_dim;
  ABSL_RAW_CHECK(x_t.rows() == c.pose_dim && x_t.cols() == c.frames, "Denoise: x_t must be (D, N)");
  ABSL_RAW_CHECK(t >= 0 && t < c.diffusion_steps, "Denoise: t outside [0, T)");
  ABSL_RAW_CHECK(style_vector.size() == c.style_dim, "Denoise: the style vector has style_dim values");
  ABSL_RAW_CHECK(context.pooled.size() == d && context.keys.size() == w.blocks.size() &&
                     context.values.size() == w.blocks.size(),
                 "Denoise: a context of another model");
  const int m = static_cast<int>(context.keys.front().cols());
  // All scratch of the call, allocated once here.
  Eigen::MatrixXf x(d, n), h(d, n), qkv(3 * d, n), attn(d, n), delta(d, n), ff(4 * d, n), scores(n, n),
      cross_scores(m, n);
  Eigen::VectorXf emb(d), te_hidden(4 * d), cond(d), style_scale(d), film(6 * d), gain(d);

  // The motion as n tokens of k frames (frame-major): a (D, N) column-major matrix is (k D, n) in place.
  const Eigen::Map<const Eigen::MatrixXf> tokens_in(x_t.data(), kd, n);
  w.motion_in.Apply(tokens_in, x);
  x += w.motion_pos;

  // cond = time_fc2(SiLU(time_fc1(emb(t)))) + pooled music; the blocks read SiLU(cond).
  TimestepEmbedding(t, emb);
  w.time_fc1.Apply(emb, te_hidden);
  SiluInPlace(te_hidden);
  w.time_fc2.Apply(te_hidden, cond);
  cond += context.pooled;
  SiluInPlace(cond);

  // delta (1 + scale) + shift, added to x: FiLM of a sub-layer's output by rows (2i, 2i + 1) of the film.
  auto add_film = [&](int i) {
    gain.array() = 1.0f + film.segment(2 * i * d, d).array();
    delta.array().colwise() *= gain.array();
    delta.colwise() += film.segment((2 * i + 1) * d, d);
    x += delta;
  };

  for (size_t bi = 0; bi < w.blocks.size(); ++bi) {
    const Impl::DecoderBlock& b = w.blocks[bi];
    // Style Modulation: x += x / (||x|| r + 1e-6) * (W_style sv + b_style), per token.
    b.style.Apply(style_vector, style_scale);
    for (int j = 0; j < n; ++j) {
      const float norm = static_cast<float>(x.col(j).cast<double>().norm());
      const float denom = norm * c.style_mod_r + kStyleModEps;
      x.col(j).array() += x.col(j).array() / denom * style_scale.array();
    }
    b.film.Apply(cond, film);

    b.norm1.Apply(x, h);
    b.self_qkv.Apply(h, qkv);
    Attend(qkv.topRows(d), qkv.middleRows(d, d), qkv.bottomRows(d), c.n_heads, scores, attn);
    b.self_o.Apply(attn, delta);
    add_film(0);

    b.norm2.Apply(x, h);
    auto q = qkv.topRows(d);
    b.cross_q.Apply(h, q);
    Attend(q, context.keys[bi], context.values[bi], c.n_heads, cross_scores, attn);
    b.cross_o.Apply(attn, delta);
    add_film(1);

    b.norm3.Apply(x, h);
    b.fc1.Apply(h, ff);
    GeluInPlace(ff);
    b.fc2.Apply(ff, delta);
    add_film(2);
  }
  w.norm_f.Apply(x, h);
  x0->resize(c.pose_dim, c.frames);
  Eigen::Map<Eigen::MatrixXf> tokens_out(x0->data(), kd, n);
  w.out.Apply(h, tokens_out);
  if (c.prediction == SgmdConfig::Prediction::kV) {
    // x0 = sqrt(abar) x_t - sqrt(1 - abar) v, in float as the reference's (its schedule is float32).
    const float abar = alphas_cumprod_[t];
    const float a = std::sqrt(abar), b = std::sqrt(1.0f - abar);
    x0->array() = a * x_t.array() - b * x0->array();
  }
}

}  // namespace dance::engine
