#include "engine/model/style_modulation.h"

#include "absl/strings/str_cat.h"

namespace dance::engine {

absl::StatusOr<StyleModulationWeights> StyleModulationWeights::Load(const WeightsFile& file,
                                                                    const std::string& prefix, int d, int d_s) {
  StyleModulationWeights sm;
  absl::StatusOr<RowMatrix> w = LoadMatrix(file, absl::StrCat(prefix, ".weight"), d, d_s);
  if (!w.ok()) return w.status();
  sm.w = *std::move(w);
  absl::StatusOr<Eigen::VectorXf> b = LoadVector(file, absl::StrCat(prefix, ".bias"), d);
  if (!b.ok()) return b.status();
  sm.b = *std::move(b);
  return sm;
}

void ApplyStyleModulation(ColsRef x, const ConstColsRef& factors, int tokens_per_lane, float r) {
  for (Eigen::Index j = 0; j < x.cols(); ++j) {
    const float scale = 1.0f / (x.col(j).norm() * r + 1e-6f);
    x.col(j) += (x.col(j) * scale).cwiseProduct(factors.col(j / tokens_per_lane));
  }
}

}  // namespace dance::engine
