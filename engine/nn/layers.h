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

// In place, element-wise.
template <typename Derived>
void SiluInPlace(Eigen::MatrixBase<Derived>& x) {
  x = x.unaryExpr([](float v) { return Silu(v); });
}

// out = w * x. For a few columns (one session's tokens) it runs one matrix-vector product per column, which
// reads the weights in place; for more it is one GEMM, whose packing cost is then shared by many columns.
// (Eigen's GEMM repacks the whole weight matrix on every call, which dominated single-session steps.)
void MatMul(const RowMatrix& w, const ConstColsRef& x, ColsRef out);
inline constexpr int kGemvMaxColumns = 4;

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
