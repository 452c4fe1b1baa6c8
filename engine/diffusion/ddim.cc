#include "engine/diffusion/ddim.h"

#include <algorithm>
#include <cmath>
#include <cstdint>

#include "absl/base/internal/raw_logging.h"

namespace dance::engine {

std::vector<int> DdimTimesteps(int total_steps, int steps) {
  ABSL_RAW_CHECK(total_steps >= 1, "DdimTimesteps: total_steps must be >= 1");
  steps = std::clamp(steps, 1, total_steps);
  if (steps == 1) return {total_steps - 1};
  std::vector<int> taus(steps);
  for (int i = 0; i < steps; ++i) {
    // Python's int(round(a / b)) on the exact integer product: the quotient rounded once to double, then to
    // nearest with ties to even (std::nearbyint in the default rounding mode), e.g. 499.5 -> 500, 249.5 -> 250.
    const int64_t num = static_cast<int64_t>(steps - 1 - i) * (total_steps - 1);
    taus[i] = static_cast<int>(std::nearbyint(static_cast<double>(num) / static_cast<double>(steps - 1)));
  }
  return taus;
}

void FillStandardNormal(std::mt19937_64& gen, Eigen::MatrixXf* out) {
  constexpr double kTwoPi = 6.283185307179586476925286766559;
  constexpr double kInv2Pow53 = 1.0 / 9007199254740992.0;  // 2^-53
  float* data = out->data();
  for (Eigen::Index i = 0; i < out->size(); ++i) {
    const double u1 = static_cast<double>(gen() >> 11) * kInv2Pow53;
    const double u2 = static_cast<double>(gen() >> 11) * kInv2Pow53;
    // 1 - u1 lies in (0, 1], so the log is finite.
    data[i] = static_cast<float>(std::sqrt(-2.0 * std::log(1.0 - u1)) * std::cos(kTwoPi * u2));
  }
}

Eigen::MatrixXf SampleWindow(const SgmdModel& model, const SgmdModel::Context& context,
                             const SgmdModel::Context& null_context, const Eigen::VectorXf& style_vector,
                             const Eigen::MatrixXf& noise, const DdimOptions& options, const WindowKnown* known,
                             const std::function<void(int, int)>& progress) {
  const SgmdConfig& c = model.config();
  ABSL_RAW_CHECK(noise.rows() == c.pose_dim && noise.cols() == c.frames, "SampleWindow: noise must be (D, N)");
  const bool imposed = known != nullptr && !known->empty();
  if (imposed) {
    ABSL_RAW_CHECK(known->mask.rows() == c.pose_dim && known->mask.cols() == c.frames &&
                       known->values.rows() == c.pose_dim && known->values.cols() == c.frames,
                   "SampleWindow: known values and mask must be (D, N)");
  }
  const std::vector<double>& abar = model.alphas_cumprod();
  const std::vector<int> taus = DdimTimesteps(c.diffusion_steps, options.steps);
  const int steps = static_cast<int>(taus.size());
  const bool guided = options.guidance != 1.0f;
  // Scalars are computed in double and applied to float32 tensors, as the reference does with Python floats
  // times torch float32 tensors.
  const float w = options.guidance;
  const float w_null = static_cast<float>(1.0 - static_cast<double>(options.guidance));

  Eigen::MatrixXf x = noise;                         // (D, N)
  Eigen::MatrixXf x0(c.pose_dim, c.frames);          // (D, N)
  Eigen::MatrixXf x0_null;                           // (D, N) when guided
  Eigen::MatrixXf eps(c.pose_dim, c.frames);         // (D, N)
  Eigen::MatrixXf inverse_mask;                      // (D, N) 1 - M
  if (guided) x0_null.resize(c.pose_dim, c.frames);
  if (imposed) inverse_mask = 1.0f - known->mask.array();

  // x = M (sqrt(abar_t) k + sqrt(1 - abar_t) e) + (1 - M) x: the known values noised to step t with the
  // window's own noise.
  auto impose = [&](int t) {
    if (!imposed) return;
    const float a = static_cast<float>(std::sqrt(abar[t]));
    const float b = static_cast<float>(std::sqrt(1.0 - abar[t]));
    x.array() = known->mask.array() * (a * known->values.array() + b * noise.array()) +
                inverse_mask.array() * x.array();
  };

  impose(taus[0]);
  for (int i = 0; i < steps; ++i) {
    const int t = taus[i];
    model.Denoise(x, t, context, style_vector, &x0);
    if (guided) {
      model.Denoise(x, t, null_context, style_vector, &x0_null);
      x0.array() = w * x0.array() + w_null * x0_null.array();
    }
    if (i == steps - 1) {
      if (imposed) {
        x.array() = known->mask.array() * known->values.array() + inverse_mask.array() * x0.array();
      } else {
        x = x0;
      }
    } else {
      const int t_next = taus[i + 1];
      const float a = static_cast<float>(std::sqrt(abar[t]));
      const float b = static_cast<float>(std::sqrt(1.0 - abar[t]));
      const float a_next = static_cast<float>(std::sqrt(abar[t_next]));
      const float b_next = static_cast<float>(std::sqrt(1.0 - abar[t_next]));
      eps.array() = (x.array() - a * x0.array()) / b;
      x.array() = a_next * x0.array() + b_next * eps.array();
      impose(t_next);
    }
    if (progress) progress(i + 1, steps);
  }
  return x;
}

}  // namespace dance::engine
