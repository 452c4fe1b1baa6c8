// Seeded sampling: greedy, temperature, top-k, top-p, guidance, option validation.
#include "engine/nn/sampling.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <numeric>

#include "gtest/gtest.h"

namespace dance::engine {
namespace {

TEST(Sampling, GreedyIsArgmaxLowestIndexOnTiesAndDrawsNothing) {
  std::mt19937_64 gen(1), untouched(1);
  SamplerScratch scratch(5);
  const std::vector<float> logits = {0.0f, 3.0f, -1.0f, 3.0f, 2.0f};
  EXPECT_EQ(SampleCode(logits, {.temperature = 0.0f}, gen, scratch), 1);
  EXPECT_EQ(gen(), untouched());
}

TEST(Sampling, SameSeedSameCodes) {
  const std::vector<float> logits = {0.1f, 0.5f, 0.2f, 0.9f, 0.3f, 0.0f};
  std::mt19937_64 a(42), b(42);
  SamplerScratch sa(6), sb(6);
  for (int i = 0; i < 100; ++i) EXPECT_EQ(SampleCode(logits, {}, a, sa), SampleCode(logits, {}, b, sb));
}

TEST(Sampling, FrequenciesFollowTheSoftmax) {
  const std::vector<float> logits = {0.0f, std::log(3.0f)};  // probabilities 1/4, 3/4
  std::mt19937_64 gen(7);
  SamplerScratch scratch(2);
  int ones = 0;
  const int n = 20000;
  for (int i = 0; i < n; ++i) ones += SampleCode(logits, {}, gen, scratch);
  EXPECT_NEAR(static_cast<double>(ones) / n, 0.75, 0.015);
}

TEST(Sampling, TopKAndTopPRestrictTheCandidates) {
  const std::vector<float> logits = {1.0f, 4.0f, 3.0f, 2.0f, 0.0f};
  std::mt19937_64 gen(3);
  SamplerScratch scratch(5);
  std::map<int, int> seen;
  for (int i = 0; i < 2000; ++i) ++seen[SampleCode(logits, {.top_k = 2}, gen, scratch)];
  EXPECT_EQ(seen.size(), 2u);
  EXPECT_TRUE(seen.count(1) && seen.count(2));
  seen.clear();
  // p = softmax: 0.64, 0.24, 0.09, ... ; top_p 0.5 keeps only the best code.
  for (int i = 0; i < 500; ++i) ++seen[SampleCode(logits, {.top_p = 0.5f}, gen, scratch)];
  EXPECT_EQ(seen.size(), 1u);
  EXPECT_EQ(seen.begin()->first, 1);
}

TEST(Sampling, LowTemperatureConcentrates) {
  const std::vector<float> logits = {1.0f, 1.5f, 0.5f};
  std::mt19937_64 gen(9);
  SamplerScratch scratch(3);
  for (int i = 0; i < 200; ++i) EXPECT_EQ(SampleCode(logits, {.temperature = 0.01f}, gen, scratch), 1);
}

TEST(Sampling, GuidanceExtrapolates) {
  const std::vector<float> uncond = {1.0f, 2.0f};
  std::vector<float> cond = {2.0f, 2.0f};
  ApplyGuidance(uncond, 3.0f, absl::MakeSpan(cond));
  EXPECT_FLOAT_EQ(cond[0], 4.0f);
  EXPECT_FLOAT_EQ(cond[1], 2.0f);
}

// The contract written plainly (full sort, docs/model.md section 6), to check the lazily sorted walk
// against: the same code for every draw.
int ReferenceSample(const std::vector<float>& logits, const SamplingOptions& o, std::mt19937_64& gen) {
  const int n = static_cast<int>(logits.size());
  const float max_logit = *std::max_element(logits.begin(), logits.end());
  std::vector<double> p(n);
  const double inv_t = 1.0 / static_cast<double>(o.temperature);
  for (int i = 0; i < n; ++i) p[i] = std::exp((logits[i] - max_logit) * inv_t);
  std::vector<int> order(n);
  std::iota(order.begin(), order.end(), 0);
  std::sort(order.begin(), order.end(), [&p](int a, int b) { return p[a] > p[b] || (p[a] == p[b] && a < b); });
  int keep = o.top_k > 0 && o.top_k < n ? o.top_k : n;
  double total = 0.0;
  if (keep < n) {
    for (int i = 0; i < keep; ++i) total += p[order[i]];
  } else {
    for (int i = 0; i < n; ++i) total += p[i];  // index order when nothing is cut
  }
  if (o.top_p > 0.0f && o.top_p < 1.0f) {  // negative: the model's default, resolved by sessions
    double cum = 0.0;
    int i = 0;
    while (i < keep && cum < o.top_p * total) cum += p[order[i++]];
    keep = i;
    total = cum;
  }
  const double u = UniformDraw(gen) * total;
  double cum = 0.0;
  for (int i = 0; i < keep; ++i) {
    cum += p[order[i]];
    if (cum > u) return order[i];
  }
  return order[keep - 1];
}

TEST(Sampling, LazyWalkMatchesTheFullSortContract) {
  std::mt19937_64 data(3);
  std::normal_distribution<float> normal(0.0f, 1.0f);
  SamplerScratch scratch(512);
  const SamplingOptions options[] = {{}, {.temperature = 0.7f}, {.temperature = 1.5f, .top_k = 40},
                                     {.top_p = 0.9f}, {.temperature = 0.9f, .top_k = 100, .top_p = 0.5f},
                                     {.top_k = 1}, {.top_k = 512}, {.top_p = 1e-6f}};
  int checked = 0;
  for (int trial = 0; trial < 300; ++trial) {
    // Peaked and flat logit vectors, some with ties (rounded values).
    std::vector<float> logits(512);
    const float scale = trial % 3 == 0 ? 0.3f : trial % 3 == 1 ? 3.0f : 8.0f;
    for (float& l : logits) l = scale * normal(data);
    if (trial % 5 == 0) {
      for (float& l : logits) l = std::round(l);
    }
    for (const SamplingOptions& o : options) {
      std::mt19937_64 a(trial), b(trial);
      for (int draw = 0; draw < 4; ++draw) {
        ASSERT_EQ(SampleCode(logits, o, a, scratch), ReferenceSample(logits, o, b))
            << "trial " << trial << " T " << o.temperature << " k " << o.top_k << " p " << o.top_p;
        ++checked;
      }
    }
  }
  EXPECT_EQ(checked, 300 * 8 * 4);
}

TEST(Sampling, ValidationNamesTheBadField) {
  EXPECT_TRUE(ValidateSamplingOptions({}).ok());
  EXPECT_FALSE(ValidateSamplingOptions({.temperature = -0.1f}).ok());
  EXPECT_FALSE(ValidateSamplingOptions({.top_k = -1}).ok());
  EXPECT_FALSE(ValidateSamplingOptions({.top_p = 0.0f}).ok());
  EXPECT_FALSE(ValidateSamplingOptions({.top_p = 1.5f}).ok());
  EXPECT_TRUE(ValidateSamplingOptions({.guidance = kModelDefaultGuidance}).ok());  // the model's default
  EXPECT_FALSE(ValidateSamplingOptions({.guidance = 100.5f}).ok());
  EXPECT_TRUE(ValidateSamplingOptions({.top_p = kModelDefaultTopP}).ok());
  EXPECT_FALSE(ValidateSamplingOptions({.top_p = std::nanf("")}).ok());
  EXPECT_FALSE(ValidateSamplingOptions({.guidance = std::nanf("")}).ok());
  EXPECT_TRUE(ValidateSamplingOptions({.music_guidance = kModelDefaultMusicGuidance}).ok());
  EXPECT_TRUE(ValidateSamplingOptions({.music_guidance = 0.0f}).ok());
  EXPECT_FALSE(ValidateSamplingOptions({.music_guidance = 100.5f}).ok());
  EXPECT_FALSE(ValidateSamplingOptions({.music_guidance = std::nanf("")}).ok());
  EXPECT_NE(ValidateSamplingOptions({.music_guidance = 101.0f}).message().find("music_guidance"), std::string::npos);
  EXPECT_NE(ValidateSamplingOptions({.temperature = -1.0f}).message().find("temperature"), std::string::npos);
}

}  // namespace
}  // namespace dance::engine
