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
  if (!((o.top_p > 0.0f && o.top_p <= 1.0f) || o.top_p < 0.0f) || !std::isfinite(o.top_p)) {
    return absl::InvalidArgumentError(
        absl::StrCat("sampling: top_p must be in (0, 1] (negative = the model's default), got ", o.top_p));
  }
  if (!(o.guidance <= 100.0f) || !std::isfinite(o.guidance)) {
    return absl::InvalidArgumentError(
        absl::StrCat("sampling: guidance must be <= 100 (negative = the model's default), got ", o.guidance));
  }
  if (!(o.music_guidance <= 100.0f) || !std::isfinite(o.music_guidance)) {
    return absl::InvalidArgumentError(absl::StrCat(
        "sampling: music_guidance must be <= 100 (negative = the model's default), got ", o.music_guidance));
  }
  if (!(o.period_lock <= 100.0f) || !std::isfinite(o.period_lock)) {
    return absl::InvalidArgumentError(
        absl::StrCat("sampling: period_lock must be <= 100 (negative = the model's default), got ", o.period_lock));
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
  // Scalar std::exp on purpose: a vectorised exp that peels unaligned ends computes some positions on a
  // scalar path whose last bit differs, which turns equal logits into unequal probabilities and makes the
  // code depend on the buffer's address.
  for (int i = 0; i < n; ++i) scratch.probs[i] = std::exp((logits[i] - max_logit) * inv_t);
  std::iota(scratch.order.begin(), scratch.order.end(), 0);
  const std::vector<double>& p = scratch.probs;
  auto more_likely = [&p](int a, int b) { return p[a] > p[b] || (p[a] == p[b] && a < b); };
  // The walk below only ever reads a short prefix of the probability-sorted candidates (the mass sits in
  // a few codes), so the order is built lazily: order[0, sorted) is sorted, the rest holds the others.
  // Sorting all K codes was ~10 % of a server's CPU.
  int sorted = 0;
  auto sorted_prefix = [&](int m) {  // afterwards order[0, m) is sorted
    if (m <= sorted) return;
    m = std::max(m, std::min(n, 2 * sorted + 16));  // grow geometrically
    std::partial_sort(scratch.order.begin() + sorted, scratch.order.begin() + m, scratch.order.end(),
                      more_likely);
    sorted = m;
  };
  int keep = n;
  double total = 0.0;
  if (options.top_k > 0 && options.top_k < n) {
    keep = options.top_k;
    sorted_prefix(keep);
    for (int i = 0; i < keep; ++i) total += p[scratch.order[i]];
  } else {
    for (int i = 0; i < n; ++i) total += p[i];
  }
  if (options.top_p > 0.0f && options.top_p < 1.0f) {
    const double target = static_cast<double>(options.top_p) * total;
    double cum = 0.0;
    int i = 0;
    while (i < keep) {
      sorted_prefix(i + 1);
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
    sorted_prefix(i + 1);
    cum += p[scratch.order[i]];
    if (cum > u) return scratch.order[i];
  }
  sorted_prefix(keep);
  return scratch.order[keep - 1];
}

}  // namespace dance::engine
