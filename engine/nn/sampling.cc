#include "engine/nn/sampling.h"

#include <algorithm>
#include <cmath>
#include <numeric>

#include "absl/strings/str_cat.h"

namespace dance::engine {

absl::Status ValidateSamplingOptions(const SamplingOptions& o) {
  if (!(o.temperature >= 0.0f) || !std::isfinite(o.temperature)) {
    return absl::InvalidArgumentError(absl::StrCat("sampling: temperature must be >= 0, got ", o.temperature));
  }
  if (o.top_k < 0) return absl::InvalidArgumentError(absl::StrCat("sampling: top_k must be >= 0, got ", o.top_k));
  if (!(o.top_p > 0.0f && o.top_p <= 1.0f)) {
    return absl::InvalidArgumentError(absl::StrCat("sampling: top_p must be in (0, 1], got ", o.top_p));
  }
  if (!(o.guidance >= 0.0f) || !std::isfinite(o.guidance)) {
    return absl::InvalidArgumentError(absl::StrCat("sampling: guidance must be >= 0, got ", o.guidance));
  }
  return absl::OkStatus();
}

void ApplyGuidance(absl::Span<const float> logits_u, float w, absl::Span<float> logits_c) {
  for (size_t i = 0; i < logits_c.size(); ++i) logits_c[i] = logits_u[i] + w * (logits_c[i] - logits_u[i]);
}

int SampleCode(absl::Span<const float> logits, const SamplingOptions& options, std::mt19937_64& gen,
               SamplerScratch& scratch) {
  const int n = static_cast<int>(logits.size());
  if (options.temperature == 0.0f) {
    int best = 0;
    for (int i = 1; i < n; ++i) {
      if (logits[i] > logits[best]) best = i;
    }
    return best;
  }
  scratch.order.resize(n);
  scratch.probs.resize(n);
  const float max_logit = *std::max_element(logits.begin(), logits.end());
  const double inv_t = 1.0 / static_cast<double>(options.temperature);
  for (int i = 0; i < n; ++i) scratch.probs[i] = std::exp((logits[i] - max_logit) * inv_t);
  std::iota(scratch.order.begin(), scratch.order.end(), 0);
  const std::vector<double>& p = scratch.probs;
  // std::sort with an index tie-break: deterministic, and unlike stable_sort it never allocates.
  std::sort(scratch.order.begin(), scratch.order.end(),
            [&p](int a, int b) { return p[a] > p[b] || (p[a] == p[b] && a < b); });
  int keep = n;
  if (options.top_k > 0) keep = std::min(keep, options.top_k);
  double total = 0.0;
  for (int i = 0; i < keep; ++i) total += p[scratch.order[i]];
  if (options.top_p < 1.0f) {
    const double target = static_cast<double>(options.top_p) * total;
    double cum = 0.0;
    int i = 0;
    while (i < keep) {
      cum += p[scratch.order[i]];
      ++i;
      if (cum >= target) break;
    }
    keep = i;
    total = cum;
  }
  const double u = UniformDraw(gen) * total;
  double cum = 0.0;
  for (int i = 0; i < keep; ++i) {
    cum += p[scratch.order[i]];
    if (cum > u) return scratch.order[i];
  }
  return scratch.order[keep - 1];
}

}  // namespace dance::engine
