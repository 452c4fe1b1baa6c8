#include "engine/nn/layers.h"

#include <cstring>

#include "absl/strings/str_cat.h"

namespace dance::engine {

void MatMul(const RowMatrix& w, const ConstColsRef& x, ColsRef out) {
  if (x.cols() <= kGemvMaxColumns) {
    for (Eigen::Index j = 0; j < x.cols(); ++j) out.col(j).noalias() = w * x.col(j);
  } else {
    out.noalias() = w * x;
  }
}

void RmsNorm(const ConstColsRef& x, const Eigen::VectorXf& weight, float eps, ColsRef out) {
  const Eigen::Index d = x.rows();
  for (Eigen::Index j = 0; j < x.cols(); ++j) {
    const float ms = x.col(j).squaredNorm() / static_cast<float>(d);
    const float inv = 1.0f / std::sqrt(ms + eps);
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
  gate = gate.unaryExpr([](float v) { return Silu(v); }).cwiseProduct(up);
  MatMul(w_down, gate, out);
}

}  // namespace dance::engine
