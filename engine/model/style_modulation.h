// SGMD style modulation (docs/model.md section 4), applied at the start of every block:
//   x += x / (||x||_2 * r + 1e-6) * f,    f = W_sm sv + b_sm  (precomputed per lane and block)
//
// Thread safety: pure functions of their arguments.
#ifndef DANCE_ENGINE_MODEL_STYLE_MODULATION_H_
#define DANCE_ENGINE_MODEL_STYLE_MODULATION_H_

#include "engine/nn/layers.h"

namespace dance::engine {

// Weights of one block's style modulation.
struct StyleModulationWeights {
  RowMatrix w;        // (d, d_s)
  Eigen::VectorXf b;  // (d)

  // Loads `<prefix>.weight` (d, d_s) and `<prefix>.bias` (d).
  static absl::StatusOr<StyleModulationWeights> Load(const WeightsFile& file, const std::string& prefix, int d,
                                                     int d_s);
  // The additive factor f for style vector `sv` (d_s).
  Eigen::VectorXf Factor(const Eigen::VectorXf& sv) const { return w * sv + b; }
};

// x: (d, tokens_per_lane * L), factors: (d, L); token j belongs to lane j / tokens_per_lane.
void ApplyStyleModulation(ColsRef x, const ConstColsRef& factors, int tokens_per_lane, float r);

}  // namespace dance::engine

#endif  // DANCE_ENGINE_MODEL_STYLE_MODULATION_H_
