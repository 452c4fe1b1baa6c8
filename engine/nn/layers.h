// Small numeric building blocks shared by the sequence model and the VQ decoder.
//
// Memory layout convention (docs/engine.md): activations are column-major `Eigen::MatrixXf` with one
// token per column, (features, tokens); weights are row-major `RowMatrix` exactly as stored in the file
// and as torch keeps them, (out, in), so a Linear is `y = W * x` over all columns at once (one GEMM per
// batch). Functions write into caller-owned outputs that are already sized: nothing here allocates, so
// the engine's hot path can call them with preallocated buffers.
//
// Thread safety: pure functions of their arguments.
#ifndef DANCE_ENGINE_NN_LAYERS_H_
#define DANCE_ENGINE_NN_LAYERS_H_

#include <cmath>

#include "Eigen/Core"
#include "absl/status/statusor.h"
#include "engine/nn/weights_file.h"

namespace dance::engine {

using RowMatrix = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
// A view of some columns of an activation matrix (e.g. every third token), (features, tokens).
using ColsRef = Eigen::Ref<Eigen::MatrixXf, 0, Eigen::OuterStride<>>;
using ConstColsRef = Eigen::Ref<const Eigen::MatrixXf, 0, Eigen::OuterStride<>>;

inline float Sigmoid(float x) { return 1.0f / (1.0f + std::exp(-x)); }
inline float Silu(float x) { return x / (1.0f + std::exp(-x)); }
// torch.nn.functional.softplus with beta 1, threshold 20.
inline float Softplus(float x) { return x > 20.0f ? x : std::log1p(std::exp(x)); }

// Element-wise, vectorised (Eigen's packet exp/log1p; within a few ulp of the scalar functions above).
// SiLU(x) = x / (1 + exp(-x)). `out` may be `x`.
template <typename In, typename Out>
void SiluTo(const Eigen::ArrayBase<In>& x, Eigen::ArrayBase<Out>& out) {
  out.derived() = x / (1.0f + (-x).exp());
}
template <typename Derived>
void SiluInPlace(Eigen::MatrixBase<Derived>& x) {
  auto a = x.array();
  SiluTo(a, a);
}
template <typename Derived>
void SiluInPlace(Eigen::MatrixBase<Derived>&& x) {
  SiluInPlace(x);
}
// Softplus as torch (beta 1, threshold 20): x > 20 ? x : log1p(exp(x)).
template <typename Derived>
void SoftplusInPlace(Eigen::MatrixBase<Derived>& x) {
  auto a = x.array();
  // max(x, .) instead of a select (not vectorised by Eigen 3.4): for x > 20, log1p(exp(20)) rounds to 20 < x;
  // below, log1p(exp(x)) > x (up to a rounding ulp near 20).
  a = a.max(a.min(20.0f).exp().log1p());
}

// out = w * x. For a few columns (one session's tokens, one lane's decoder frames) a register-blocked
// kernel reads each weight row once for all columns (AVX2+FMA builds; a matrix-vector product per column
// otherwise); for more it is one GEMM, whose packing cost is then shared by many columns. (Eigen's GEMM
// repacks the whole weight matrix on every call, which dominated single-session steps.)
void MatMul(const RowMatrix& w, const ConstColsRef& x, ColsRef out);
inline constexpr int kGemvMaxColumns = 8;

// out[q] = sum_i a[i] * b[q * b_stride + i] for q = 0, 1, 2 (three dot products sharing `a`).
void Dot3(const float* a, const float* b, Eigen::Index b_stride, int n, float out[3]);

// out(:, j) = x(:, j) / sqrt(mean(x(:, j)^2) + eps) * weight. `out` may alias `x`.
void RmsNorm(const ConstColsRef& x, const Eigen::VectorXf& weight, float eps, ColsRef out);

// Copies a rank-2 tensor (rows, cols) into a RowMatrix; InvalidArgument if the shape differs.
absl::StatusOr<RowMatrix> LoadMatrix(const WeightsFile& file, const std::string& name, int64_t rows, int64_t cols);
// Copies a rank-1 tensor (n) into a vector.
absl::StatusOr<Eigen::VectorXf> LoadVector(const WeightsFile& file, const std::string& name, int64_t n);

// GatedMLP(h) = W_down (SiLU(W_gate h) * W_up h), no biases; hidden width = w_gate.rows().
struct GatedMlp {
  RowMatrix w_gate;  // (d_ff, d)
  RowMatrix w_up;    // (d_ff, d)
  RowMatrix w_down;  // (d, d_ff)

  // Loads `<prefix>.gate`, `<prefix>.up`, `<prefix>.down`.
  static absl::StatusOr<GatedMlp> Load(const WeightsFile& file, const std::string& prefix, int64_t d, int64_t d_ff);

  // out = GatedMLP(h); gate and up are (d_ff, tokens) scratch views sized by the caller.
  void Apply(const ConstColsRef& h, ColsRef gate, ColsRef up, ColsRef out) const;
};

}  // namespace dance::engine

#endif  // DANCE_ENGINE_NN_LAYERS_H_
