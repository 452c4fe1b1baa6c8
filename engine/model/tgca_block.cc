#include "engine/model/tgca_block.h"

#include <algorithm>
#include <cmath>
#include <limits>

#if defined(__AVX2__) && defined(__FMA__)
#include <immintrin.h>
#endif

#include "absl/strings/str_cat.h"

namespace dance::engine {
namespace {

constexpr float kNormEps = 1e-5f;

}  // namespace

absl::StatusOr<TgcaBlock> TgcaBlock::Load(const WeightsFile& file, const std::string& prefix, const SeqConfig& c) {
  TgcaBlock b;
  b.c_ = c;
  const int d = c.d_model;
  for (int h = 0; h < c.n_heads; ++h) {
    b.slopes_.push_back(std::pow(2.0f, -8.0f * static_cast<float>(h + 1) / static_cast<float>(c.n_heads)));
  }
  absl::StatusOr<StyleModulationWeights> sm = StyleModulationWeights::Load(file, prefix + ".style", d,
                                                                           c.style_dim);
  if (!sm.ok()) return sm.status();
  b.style_ = *std::move(sm);
  absl::StatusOr<Eigen::VectorXf> v = LoadVector(file, prefix + ".norm1.weight", d);
  if (!v.ok()) return v.status();
  b.norm1_ = *std::move(v);
  v = LoadVector(file, prefix + ".norm2.weight", d);
  if (!v.ok()) return v.status();
  b.norm2_ = *std::move(v);
  b.w_in_g_.resize(2 * d, d);
  b.w_qkv_.resize(3 * d, d);
  const std::pair<const char*, RowMatrix*> stacked[] = {
      {"w_in", &b.w_in_g_}, {"w_g", &b.w_in_g_}, {"w_q", &b.w_qkv_}, {"w_k", &b.w_qkv_}, {"w_v", &b.w_qkv_}};
  const int row0[] = {0, d, 0, d, 2 * d};
  for (int i = 0; i < 5; ++i) {
    absl::StatusOr<RowMatrix> m = LoadMatrix(file, absl::StrCat(prefix, ".", stacked[i].first), d, d);
    if (!m.ok()) {
      // The no-gate ablation has no W_g: use a gate of zeros and replace SiLU(0) = 0 by 1 in Step.
      if (i == 1 && !c.use_gate) {
        b.w_in_g_.middleRows(d, d).setZero();
        continue;
      }
      return m.status();
    }
    stacked[i].second->middleRows(row0[i], d) = *m;
  }
  absl::StatusOr<RowMatrix> wo = LoadMatrix(file, prefix + ".w_o", d, d);
  if (!wo.ok()) return wo.status();
  b.w_o_ = *std::move(wo);
  absl::StatusOr<GatedMlp> mlp = GatedMlp::Load(file, prefix + ".mlp", d, c.d_ff());
  if (!mlp.ok()) return mlp.status();
  b.mlp_ = *std::move(mlp);
  return b;
}

void TgcaBlock::Step(absl::Span<SequenceState* const> lanes, int cache, int style_block, Workspace& ws,
                     Trace* trace, const std::string& name) const {
  const int n = static_cast<int>(lanes.size());
  const int d = c_.d_model, t = 3 * n;
  auto x = ws.x.leftCols(t);
  auto h = ws.h.leftCols(t);
  auto zg = ws.zg.leftCols(t);
  for (int b = 0; b < n; ++b) ws.style.col(b) = lanes[b]->style_bias.col(style_block);
  ApplyStyleModulation(x, ws.style.leftCols(n), 3, c_.style_mod_r);
  RmsNorm(x, norm1_, kNormEps, h);
  MatMul(w_in_g_, h, zg);
  if (c_.use_gate) {
    SiluInPlace(zg);
  } else {
    SiluInPlace(zg.topRows(d));
    zg.bottomRows(d).setOnes();
  }
  MatMul(w_qkv_, zg.topRows(d), ws.qkv.leftCols(t));
  for (int b = 0; b < n; ++b) Attend(*lanes[b], cache, b, ws);
  auto attn = ws.attn.leftCols(t);
  attn.array() *= zg.bottomRows(d).array();
  auto delta = ws.delta.leftCols(t);
  MatMul(w_o_, attn, delta);
  x += delta;
  if (trace != nullptr) (*trace)[name + ".attn_out"] = x;
  RmsNorm(x, norm2_, kNormEps, h);
  mlp_.Apply(h, ws.gate.leftCols(t), ws.up.leftCols(t), delta);
  x += delta;
}

// Writes this step's keys and values into the lane's ring buffer, then attends the lane's 3 queries to
// the valid window. Scores are computed over the whole ring and masked, which keeps the step independent of
// how full the cache is. The products are tiny ((3W x d_head) by (d_head x 3)), so they are written out
// directly (one pass over each key and value column for all 3 queries) instead of going through GEMM.
void TgcaBlock::Attend(SequenceState& lane, int cache, int lane_index, Workspace& ws) const {
  const int d = c_.d_model, dh = c_.d_head(), w = c_.attn_window;
  const int64_t t = lane.step;
  const int slot = static_cast<int>(t % w);
  Eigen::MatrixXf& keys = lane.keys[cache];
  Eigen::MatrixXf& values = lane.values[cache];
  const auto qkv = ws.qkv.middleCols(3 * lane_index, 3);
  keys.middleCols(3 * slot, 3) = qkv.middleRows(d, d);
  values.middleCols(3 * slot, 3) = qkv.middleRows(2 * d, d);
  const int valid_steps = static_cast<int>(std::min<int64_t>(t + 1, w));
  const float inv_sqrt = 1.0f / std::sqrt(static_cast<float>(dh));
  const float neg_inf = -std::numeric_limits<float>::infinity();
  auto out = ws.attn.middleCols(3 * lane_index, 3);
  const Eigen::Index q_stride = ws.qkv.outerStride(), out_stride = ws.attn.outerStride();
  auto scores = ws.scores.topRows(3 * w);  // (3W, 3), column q = query (stream) q
  for (int head = 0; head < c_.n_heads; ++head) {
    const int r0 = head * dh;
    const float* q0 = qkv.data() + r0;
    const float slope = slopes_[head];
    for (int s = 0; s < w; ++s) {
      // Ring slot s holds step t' = t - ((slot - s) mod W); distance t - t' in steps.
      const int dist = (slot - s + w) % w;
      for (int j = 3 * s; j < 3 * s + 3; ++j) {
        if (dist >= valid_steps) {
          for (int q = 0; q < 3; ++q) scores(j, q) = neg_inf;
          continue;
        }
        float dot[3];
        Dot3(keys.col(j).data() + r0, q0, q_stride, dh, dot);
        for (int q = 0; q < 3; ++q) scores(j, q) = dot[q] * inv_sqrt - slope * static_cast<float>(dist);
      }
    }
    for (int q = 0; q < 3; ++q) {
      auto col = scores.col(q);
      const float m = col.maxCoeff();
      col = (col.array() - m).exp();
      col /= col.sum();
    }
    // out(:, q) = sum_j values(:, j) p(j, q) over this head's rows.
    float* o = out.data() + r0;
    for (int q = 0; q < 3; ++q) std::fill_n(o + q * out_stride, dh, 0.0f);
    int i0 = 0;
#if defined(__AVX2__) && defined(__FMA__)
    // 8 rows at a time, the three outputs held in registers over the whole ring.
    for (; i0 + 8 <= dh; i0 += 8) {
      __m256 a0 = _mm256_setzero_ps(), a1 = _mm256_setzero_ps(), a2 = _mm256_setzero_ps();
      for (int j = 0; j < 3 * w; ++j) {
        const __m256 v = _mm256_loadu_ps(values.col(j).data() + r0 + i0);
        a0 = _mm256_fmadd_ps(_mm256_set1_ps(scores(j, 0)), v, a0);
        a1 = _mm256_fmadd_ps(_mm256_set1_ps(scores(j, 1)), v, a1);
        a2 = _mm256_fmadd_ps(_mm256_set1_ps(scores(j, 2)), v, a2);
      }
      _mm256_storeu_ps(o + i0, a0);
      _mm256_storeu_ps(o + out_stride + i0, a1);
      _mm256_storeu_ps(o + 2 * out_stride + i0, a2);
    }
#endif
    if (i0 < dh) {
      for (int j = 0; j < 3 * w; ++j) {
        const float* v = values.col(j).data() + r0;
        const float p0 = scores(j, 0), p1 = scores(j, 1), p2 = scores(j, 2);
        for (int i = i0; i < dh; ++i) {
          o[i] += p0 * v[i];
          o[out_stride + i] += p1 * v[i];
          o[2 * out_stride + i] += p2 * v[i];
        }
      }
    }
  }
}

}  // namespace dance::engine
