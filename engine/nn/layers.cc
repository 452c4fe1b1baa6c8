#include "engine/nn/layers.h"

#include <cstring>

#if defined(__AVX2__) && defined(__FMA__)
#include <immintrin.h>
#endif

#include "absl/strings/str_cat.h"

namespace dance::engine {

namespace {

#if defined(__AVX2__) && defined(__FMA__)
float HorizontalSum(__m256 v) {
  __m128 s = _mm_add_ps(_mm256_castps256_ps128(v), _mm256_extractf128_ps(v, 1));
  s = _mm_add_ps(s, _mm_movehl_ps(s, s));
  s = _mm_add_ss(s, _mm_movehdup_ps(s));
  return _mm_cvtss_f32(s);
}

// out(r0 + i, j) = w.row(r0 + i) . x.col(j) for i < R, j < N: R x N accumulators, each weight chunk is
// loaded once for all N columns.
template <int R, int N>
void RowBlock(const float* w, Eigen::Index k, Eigen::Index r0, const float* x, Eigen::Index x_stride, float* out,
              Eigen::Index out_stride) {
  __m256 acc[R][N];
  for (int i = 0; i < R; ++i) {
    for (int j = 0; j < N; ++j) acc[i][j] = _mm256_setzero_ps();
  }
  const float* rows = w + r0 * k;
  Eigen::Index c = 0;
  for (; c + 8 <= k; c += 8) {
    __m256 xv[N];
    for (int j = 0; j < N; ++j) xv[j] = _mm256_loadu_ps(x + j * x_stride + c);
    for (int i = 0; i < R; ++i) {
      const __m256 wv = _mm256_loadu_ps(rows + i * k + c);
      for (int j = 0; j < N; ++j) acc[i][j] = _mm256_fmadd_ps(wv, xv[j], acc[i][j]);
    }
  }
  for (int i = 0; i < R; ++i) {
    for (int j = 0; j < N; ++j) {
      float sum = HorizontalSum(acc[i][j]);
      for (Eigen::Index t = c; t < k; ++t) sum += rows[i * k + t] * x[j * x_stride + t];
      out[j * out_stride + r0 + i] = sum;
    }
  }
}

template <int N>
void SmallMatMul(const RowMatrix& w, const float* x, Eigen::Index x_stride, float* out, Eigen::Index out_stride) {
  // Rows per block: R x N accumulators + N column chunks + 1 weight chunk fit in the 16 ymm registers.
  constexpr int R = N == 1 ? 8 : N == 2 ? 4 : N == 3 ? 4 : 3;
  const Eigen::Index m = w.rows(), k = w.cols();
  Eigen::Index r = 0;
  for (; r + R <= m; r += R) RowBlock<R, N>(w.data(), k, r, x, x_stride, out, out_stride);
  for (; r < m; ++r) RowBlock<1, N>(w.data(), k, r, x, x_stride, out, out_stride);
}
#endif

}  // namespace

void MatMul(const RowMatrix& w, const ConstColsRef& x, ColsRef out) {
  const Eigen::Index n = x.cols();
  if (n > kGemvMaxColumns) {
    out.noalias() = w * x;
    return;
  }
#if defined(__AVX2__) && defined(__FMA__)
  const Eigen::Index xs = x.outerStride(), os = out.outerStride();
  for (Eigen::Index j = 0; j < n;) {
    const Eigen::Index left = n - j;
    const float* xj = x.data() + j * xs;
    float* oj = out.data() + j * os;
    if (left >= 4) {
      SmallMatMul<4>(w, xj, xs, oj, os);
      j += 4;
    } else if (left == 3) {
      SmallMatMul<3>(w, xj, xs, oj, os);
      j += 3;
    } else if (left == 2) {
      SmallMatMul<2>(w, xj, xs, oj, os);
      j += 2;
    } else {
      SmallMatMul<1>(w, xj, xs, oj, os);
      j += 1;
    }
  }
#else
  for (Eigen::Index j = 0; j < n; ++j) out.col(j).noalias() = w * x.col(j);
#endif
}

void Dot3(const float* a, const float* b, Eigen::Index b_stride, int n, float out[3]) {
  int i = 0;
#if defined(__AVX2__) && defined(__FMA__)
  __m256 acc0 = _mm256_setzero_ps(), acc1 = _mm256_setzero_ps(), acc2 = _mm256_setzero_ps();
  for (; i + 8 <= n; i += 8) {
    const __m256 av = _mm256_loadu_ps(a + i);
    acc0 = _mm256_fmadd_ps(av, _mm256_loadu_ps(b + i), acc0);
    acc1 = _mm256_fmadd_ps(av, _mm256_loadu_ps(b + b_stride + i), acc1);
    acc2 = _mm256_fmadd_ps(av, _mm256_loadu_ps(b + 2 * b_stride + i), acc2);
  }
  out[0] = HorizontalSum(acc0);
  out[1] = HorizontalSum(acc1);
  out[2] = HorizontalSum(acc2);
#else
  out[0] = out[1] = out[2] = 0.0f;
#endif
  for (; i < n; ++i) {
    out[0] += a[i] * b[i];
    out[1] += a[i] * b[b_stride + i];
    out[2] += a[i] * b[2 * b_stride + i];
  }
}

void RmsNorm(const ConstColsRef& x, const Eigen::VectorXf& weight, float eps, ColsRef out) {
  const Eigen::Index d = x.rows();
  for (Eigen::Index j = 0; j < x.cols(); ++j) {
    // Mean square and its inverse root in double (the scaling stays float): with a float sum, the default
    // model's last layer drifted 9.8e-7 from the float64 reference (golden_test; 1e-6 is the target),
    // with this 5.3e-7. Measured at no cost beyond noise (engine_bench BM_Step/64).
    const double ms = x.col(j).cast<double>().squaredNorm() / static_cast<double>(d);
    const float inv = static_cast<float>(1.0 / std::sqrt(ms + eps));
    out.col(j) = x.col(j).cwiseProduct(weight) * inv;
  }
}

absl::StatusOr<RowMatrix> LoadMatrix(const WeightsFile& file, const std::string& name, int64_t rows,
                                     int64_t cols) {
  absl::StatusOr<const Tensor*> t = file.Get(name, {rows, cols});
  if (!t.ok()) return t.status();
  RowMatrix m(rows, cols);
  std::memcpy(m.data(), (*t)->data.data(), sizeof(float) * rows * cols);
  return m;
}

absl::StatusOr<Eigen::VectorXf> LoadVector(const WeightsFile& file, const std::string& name, int64_t n) {
  absl::StatusOr<const Tensor*> t = file.Get(name, {n});
  if (!t.ok()) return t.status();
  Eigen::VectorXf v(n);
  std::memcpy(v.data(), (*t)->data.data(), sizeof(float) * n);
  return v;
}

absl::StatusOr<GatedMlp> GatedMlp::Load(const WeightsFile& file, const std::string& prefix, int64_t d,
                                        int64_t d_ff) {
  GatedMlp mlp;
  absl::StatusOr<RowMatrix> m = LoadMatrix(file, absl::StrCat(prefix, ".gate"), d_ff, d);
  if (!m.ok()) return m.status();
  mlp.w_gate = *std::move(m);
  m = LoadMatrix(file, absl::StrCat(prefix, ".up"), d_ff, d);
  if (!m.ok()) return m.status();
  mlp.w_up = *std::move(m);
  m = LoadMatrix(file, absl::StrCat(prefix, ".down"), d, d_ff);
  if (!m.ok()) return m.status();
  mlp.w_down = *std::move(m);
  return mlp;
}

void GatedMlp::Apply(const ConstColsRef& h, ColsRef gate, ColsRef up, ColsRef out) const {
  MatMul(w_gate, h, gate);
  MatMul(w_up, h, up);
  gate.array() = gate.array() / (1.0f + (-gate.array()).exp()) * up.array();
  MatMul(w_down, gate, out);
}

}  // namespace dance::engine
