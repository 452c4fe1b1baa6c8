#include "engine/model/pmmm_block.h"

#include "absl/strings/str_cat.h"
#include "engine/nn/status_macros.h"

namespace dance::engine {
namespace {

constexpr float kNormEps = 1e-5f;

}  // namespace

absl::StatusOr<PmmmBlock> PmmmBlock::Load(const WeightsFile& file, const std::string& prefix, const SeqConfig& c) {
  PmmmBlock b;
  b.c_ = c;
  const int d = c.d_model, di = c.d_inner(), ds = c.d_state, r = c.dt_rank();
  const std::string m = prefix + ".mamba";
  DANCE_ASSIGN_OR_RETURN(b.style_, StyleModulationWeights::Load(file, prefix + ".style", d, c.style_dim));
  DANCE_ASSIGN_OR_RETURN(b.norm1_, LoadVector(file, prefix + ".norm1.weight", d));
  DANCE_ASSIGN_OR_RETURN(b.norm2_, LoadVector(file, prefix + ".norm2.weight", d));
  DANCE_ASSIGN_OR_RETURN(b.in_proj_, LoadMatrix(file, m + ".in_proj", 2 * di, d));
  DANCE_ASSIGN_OR_RETURN(b.conv_w_, LoadMatrix(file, m + ".conv_w", di, c.d_conv));
  DANCE_ASSIGN_OR_RETURN(b.conv_b_, LoadVector(file, m + ".conv_b", di));
  DANCE_ASSIGN_OR_RETURN(b.x_proj_, LoadMatrix(file, m + ".x_proj", r + 2 * ds, di));
  DANCE_ASSIGN_OR_RETURN(b.dt_proj_, LoadMatrix(file, m + ".dt_proj.weight", di, r));
  DANCE_ASSIGN_OR_RETURN(b.dt_bias_, LoadVector(file, m + ".dt_proj.bias", di));
  DANCE_ASSIGN_OR_RETURN(b.neg_a_, LoadMatrix(file, m + ".A_log", di, ds));
  b.neg_a_ = -b.neg_a_.array().exp();
  DANCE_ASSIGN_OR_RETURN(b.d_skip_, LoadVector(file, m + ".D", di));
  DANCE_ASSIGN_OR_RETURN(b.out_proj_, LoadMatrix(file, m + ".out_proj", d, di));
  DANCE_ASSIGN_OR_RETURN(b.mlp_, GatedMlp::Load(file, prefix + ".mlp", d, c.d_ff()));
  return b;
}

void PmmmBlock::Step(ColsRef x, absl::Span<SequenceState* const> lanes, int state, int style_block,
                     Workspace& ws) const {
  const int n = static_cast<int>(lanes.size());
  const int di = c_.d_inner(), ds = c_.d_state, r = c_.dt_rank(), kc = c_.d_conv;
  for (int b = 0; b < n; ++b) ws.style.col(b) = lanes[b]->style_bias.col(style_block);
  ApplyStyleModulation(x, ws.style.leftCols(n), 1, c_.style_mod_r);
  auto h = ws.stream_h.leftCols(n);
  RmsNorm(x, norm1_, kNormEps, h);
  auto xz = ws.xz.leftCols(n);
  MatMul(in_proj_, h, xz);
  auto conv = ws.conv_out.leftCols(n);
  for (int b = 0; b < n; ++b) {
    Eigen::MatrixXf& hist = lanes[b]->conv[state];  // (di, kc - 1), oldest first
    auto xi = xz.col(b).head(di);
    auto c = conv.col(b);
    c = conv_b_ + conv_w_.col(kc - 1).cwiseProduct(xi);
    for (int j = 0; j < kc - 1; ++j) c += conv_w_.col(j).cwiseProduct(hist.col(j));
    for (int j = 0; j + 1 < kc - 1; ++j) hist.col(j) = hist.col(j + 1);
    if (kc > 1) hist.col(kc - 2) = xi;
  }
  SiluInPlace(conv);
  auto dbc = ws.dbc.leftCols(n);
  MatMul(x_proj_, conv, dbc);
  auto dt = ws.dt.leftCols(n);
  MatMul(dt_proj_, dbc.topRows(r), dt);
  dt.colwise() += dt_bias_;
  SoftplusInPlace(dt);
  auto y = ws.y.leftCols(n);
  // Selective scan, one lane at a time, one state column (di contiguous floats) at a time:
  //   hs(:, s) = exp(dt * A(:, s)) * hs(:, s) + (dt * x) B_s;   y = sum_s hs(:, s) C_s + D * x.
  Eigen::ArrayXf& dtx = ws.dtx;  // (di) scratch
  for (int b = 0; b < n; ++b) {
    Eigen::MatrixXf& hs = lanes[b]->ssm[state];  // (di, ds)
    const auto dt_b = dt.col(b).array();
    const auto c = conv.col(b).array();
    const auto bc = dbc.col(b);
    dtx = dt_b * c;
    auto yb = y.col(b).array();
    yb.setZero();
    for (int s = 0; s < ds; ++s) {
      auto hcol = hs.col(s).array();
      hcol = hcol * (neg_a_.col(s).array() * dt_b).exp() + dtx * bc(r + s);
      yb += hcol * bc(r + ds + s);
    }
    yb += d_skip_.array() * c;
    auto z = xz.col(b).tail(di).array();
    yb *= z / (1.0f + (-z).exp());
  }
  auto delta = ws.stream_h.leftCols(n);  // h is no longer needed
  MatMul(out_proj_, y, delta);
  x += delta;
  RmsNorm(x, norm2_, kNormEps, h);
  auto mlp_out = ws.delta.leftCols(n);
  mlp_.Apply(h, ws.gate.leftCols(n), ws.up.leftCols(n), mlp_out);
  x += mlp_out;
}

}  // namespace dance::engine
