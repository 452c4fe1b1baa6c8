#include "engine/model/sequence_model.h"

#include "absl/strings/str_cat.h"
#include "engine/nn/status_macros.h"

namespace dance::engine {
namespace {

constexpr float kNormEps = 1e-5f;
constexpr char kPrefix[] = "seq.";
constexpr const char* kStreamNames[3] = {"music", "upper", "lower"};

std::string Name(const std::string& rest) { return absl::StrCat(kPrefix, rest); }

}  // namespace

absl::StatusOr<SequenceModel> SequenceModel::Load(const WeightsFile& file) {
  SequenceModel m;
  DANCE_ASSIGN_OR_RETURN(m.c_, SeqConfig::FromMetadata(file.metadata()));
  const SeqConfig& c = m.c_;
  const int d = c.d_model, k = c.codebook_size, md = c.music_dim();
  DANCE_ASSIGN_OR_RETURN(m.music_mean_, LoadVector(file, Name("music_mean"), md));
  DANCE_ASSIGN_OR_RETURN(m.music_std_, LoadVector(file, Name("music_std"), md));
  if ((m.music_std_.array() <= 0.0f).any()) {
    return absl::InvalidArgumentError("weights file: seq.music_std has a value <= 0");
  }
  DANCE_ASSIGN_OR_RETURN(m.w_music_, LoadMatrix(file, Name("embed.music.weight"), d, md));
  DANCE_ASSIGN_OR_RETURN(m.b_music_, LoadVector(file, Name("embed.music.bias"), d));
  DANCE_ASSIGN_OR_RETURN(m.embed_upper_, LoadMatrix(file, Name("embed.upper"), k + 1, d));
  DANCE_ASSIGN_OR_RETURN(m.embed_lower_, LoadMatrix(file, Name("embed.lower"), k + 1, d));
  DANCE_ASSIGN_OR_RETURN(m.embed_stream_, LoadMatrix(file, Name("embed.stream"), 3, d));
  if (c.use_pre) {
    DANCE_ASSIGN_OR_RETURN(m.w_pre_, LoadMatrix(file, Name("pre.weight"), d, c.pre_dim));
    DANCE_ASSIGN_OR_RETURN(m.b_pre_, LoadVector(file, Name("pre.bias"), d));
    DANCE_ASSIGN_OR_RETURN(m.bn_scale_, LoadVector(file, Name("pre.bn_scale"), d));
    DANCE_ASSIGN_OR_RETURN(m.bn_shift_, LoadVector(file, Name("pre.bn_shift"), d));
  }
  DANCE_ASSIGN_OR_RETURN(m.style_table_, LoadMatrix(file, Name("style.table"), c.n_styles + 1, c.style_dim));
  for (int i = 0; i < c.n_base; ++i) {
    DANCE_ASSIGN_OR_RETURN(TgcaBlock b, TgcaBlock::Load(file, Name(absl::StrCat("base.", i)), c));
    m.base_.push_back(std::move(b));
  }
  for (int i = 0; i < c.n_head; ++i) {
    for (int s = 0; s < c.n_pmmm_sets(); ++s) {
      const char* set = c.shared_mamba ? "shared" : kStreamNames[s];
      DANCE_ASSIGN_OR_RETURN(PmmmBlock b, PmmmBlock::Load(file, Name(absl::StrCat("pmmm.", i, ".", set)), c));
      m.pmmm_.push_back(std::move(b));
    }
  }
  DANCE_ASSIGN_OR_RETURN(TgcaBlock fin, TgcaBlock::Load(file, Name("final"), c));
  m.final_.push_back(std::move(fin));
  DANCE_ASSIGN_OR_RETURN(m.norm_f_, LoadVector(file, Name("norm_f.weight"), d));
  DANCE_ASSIGN_OR_RETURN(m.head_upper_, LoadMatrix(file, Name("head.upper"), k, d));
  DANCE_ASSIGN_OR_RETURN(m.head_lower_, LoadMatrix(file, Name("head.lower"), k, d));
  return m;
}

SequenceState SequenceModel::NewState() const {
  SequenceState s;
  const int d = c_.d_model;
  for (int i = 0; i < c_.n_base + 1; ++i) {
    s.keys.push_back(Eigen::MatrixXf::Zero(d, 3 * c_.attn_window));
    s.values.push_back(Eigen::MatrixXf::Zero(d, 3 * c_.attn_window));
  }
  for (int i = 0; i < c_.n_head * 3; ++i) {
    s.conv.push_back(Eigen::MatrixXf::Zero(c_.d_inner(), std::max(c_.d_conv - 1, 0)));
    s.ssm.push_back(Eigen::MatrixXf::Zero(c_.d_inner(), c_.d_state));
  }
  s.style_bias.resize(d, num_style_blocks());
  const std::pair<int, float> none[] = {{c_.n_styles, 1.0f}};
  SetStyle(StyleVector(none), &s);
  return s;
}

Eigen::VectorXf SequenceModel::StyleVector(absl::Span<const std::pair<int, float>> weights) const {
  Eigen::VectorXf sv = Eigen::VectorXf::Zero(c_.style_dim);
  for (const auto& [row, w] : weights) sv += w * style_table_.row(row).transpose();
  return sv;
}

void SequenceModel::SetStyle(const Eigen::VectorXf& sv, SequenceState* state) const {
  int col = 0;
  for (const TgcaBlock& b : base_) state->style_bias.col(col++) = b.style().Factor(sv);
  for (const PmmmBlock& b : pmmm_) state->style_bias.col(col++) = b.style().Factor(sv);
  state->style_bias.col(col) = final_[0].style().Factor(sv);
}

void SequenceModel::Step(absl::Span<const LaneInput> lanes, Workspace& ws, Trace* trace) const {
  const int n = static_cast<int>(lanes.size());
  ws.Reserve(c_, n);
  ws.states.clear();
  for (const LaneInput& in : lanes) ws.states.push_back(in.state);
  const absl::Span<SequenceState* const> states(ws.states.data(), ws.states.size());
  const int t = 3 * n, md = c_.music_dim();

  // Embedding (section 3): music Linear over normalised features, code rows, PRE, stream embedding.
  auto music = ws.music.leftCols(n);
  for (int b = 0; b < n; ++b) {
    music.col(b) = (Eigen::Map<const Eigen::VectorXf>(lanes[b].music, md) - music_mean_).cwiseQuotient(music_std_);
  }
  auto xm = ws.stream_x.leftCols(n);
  MatMul(w_music_, music, xm);
  auto x = ws.x.leftCols(t);
  for (int b = 0; b < n; ++b) {
    x.col(3 * b) = xm.col(b) + b_music_;
    x.col(3 * b + 1) = embed_upper_.row(lanes[b].upper_code).transpose();
    x.col(3 * b + 2) = embed_lower_.row(lanes[b].lower_code).transpose();
  }
  if (c_.use_pre) {
    auto pre = ws.pre.leftCols(n);
    for (int b = 0; b < n; ++b) pre.col(b) = Eigen::Map<const Eigen::VectorXf>(lanes[b].pre, c_.pre_dim);
    auto phi = ws.stream_h.leftCols(n);
    MatMul(w_pre_, pre, phi);
    phi.colwise() += b_pre_;
    phi = (phi.array().colwise() * bn_scale_.array()).colwise() + bn_shift_.array();
    phi = phi.cwiseMax(0.0f);
    for (int b = 0; b < n; ++b) x.middleCols(3 * b, 3).colwise() += phi.col(b);
  }
  for (int b = 0; b < n; ++b) x.middleCols(3 * b, 3) += embed_stream_.transpose();
  if (trace != nullptr) (*trace)["embed"] = x;

  int style_block = 0;
  for (int i = 0; i < c_.n_base; ++i) {
    const std::string name = absl::StrCat("base", i);
    base_[i].Step(states, i, style_block++, ws, trace, name);
    if (trace != nullptr) (*trace)[name] = x;
  }
  for (int i = 0; i < c_.n_head; ++i) {
    for (int s = 0; s < 3; ++s) {
      const int set = c_.shared_mamba ? 0 : s;
      // Stream s's tokens are every third column; gather them contiguous for the GEMMs.
      auto xs = ws.stream_x.leftCols(n);
      for (int b = 0; b < n; ++b) xs.col(b) = x.col(3 * b + s);
      pmmm_[i * c_.n_pmmm_sets() + set].Step(xs, states, i * 3 + s, style_block + set, ws);
      for (int b = 0; b < n; ++b) x.col(3 * b + s) = xs.col(b);
    }
    style_block += c_.n_pmmm_sets();
    if (trace != nullptr) (*trace)[absl::StrCat("pmmm", i)] = x;
  }
  final_[0].Step(states, c_.n_base, style_block, ws, trace, "final");
  if (trace != nullptr) (*trace)["final"] = x;
  auto y = ws.h.leftCols(t);
  RmsNorm(x, norm_f_, kNormEps, y);
  if (trace != nullptr) (*trace)["norm_f"] = y;
  auto yu = ws.stream_x.leftCols(n);
  auto yl = ws.stream_h.leftCols(n);
  for (int b = 0; b < n; ++b) {
    yu.col(b) = y.col(3 * b + 1);
    yl.col(b) = y.col(3 * b + 2);
  }
  MatMul(head_upper_, yu, ws.logits_u.leftCols(n));
  MatMul(head_lower_, yl, ws.logits_l.leftCols(n));
  for (SequenceState* s : ws.states) ++s->step;
}

}  // namespace dance::engine
