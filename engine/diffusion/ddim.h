// The DDIM sampler of one SGMD window with known values imposed every step (docs/diffusion.md section 4).
//
// Usage:
//   std::mt19937_64 gen(seed);
//   Eigen::MatrixXf noise(D, N);
//   FillStandardNormal(gen, &noise);                       // frame by frame, dims in order
//   WindowKnown known;                                     // or values/mask (D, N), normalised, mask 0 or 1
//   Eigen::MatrixXf x = SampleWindow(model, c, none, sv, noise, {.steps = 50, .guidance = 1}, &known);
//
// Thread safety: pure functions of their arguments (the generator is the caller's).
#ifndef DANCE_ENGINE_DIFFUSION_DDIM_H_
#define DANCE_ENGINE_DIFFUSION_DDIM_H_

#include <functional>
#include <random>
#include <vector>

#include "Eigen/Core"
#include "engine/diffusion/sgmd_model.h"

namespace dance::engine {

// tau_i = round((S-1-i) (T-1) / (S-1)), i = 0..S-1 (round half to even, as Python); S = 1: {T - 1}.
// S is clamped to [1, T]; T >= 1.
std::vector<int> DdimTimesteps(int total_steps, int steps);

// Each value sqrt(-2 ln(1 - u1)) cos(2 pi u2), u = (gen() >> 11) 2^-53, u1 then u2 per value, in the
// matrix's storage order (column-major: for a (D, N) window, frame by frame).
void FillStandardNormal(std::mt19937_64& gen, Eigen::MatrixXf* out);

// Known values (normalised) and a 0/1 mask, both (D, N); empty matrices = nothing known.
struct WindowKnown {
  Eigen::MatrixXf values;
  Eigen::MatrixXf mask;
  bool empty() const { return mask.size() == 0; }
};

struct DdimOptions {
  int steps = 50;          // S, 1..T
  float guidance = 1.0f;   // w: x0 = w D(c) + (1 - w) D(null); 1 runs one pass per step
};

// x0 of the window (D, N), normalised. `null_context` is read only when guidance != 1. `known` may be null.
// `progress`, if set, is called after each step with (steps done, steps).
Eigen::MatrixXf SampleWindow(const SgmdModel& model, const SgmdModel::Context& context,
                             const SgmdModel::Context& null_context, const Eigen::VectorXf& style_vector,
                             const Eigen::MatrixXf& noise, const DdimOptions& options, const WindowKnown* known,
                             const std::function<void(int, int)>& progress = nullptr);

}  // namespace dance::engine

#endif  // DANCE_ENGINE_DIFFUSION_DDIM_H_
