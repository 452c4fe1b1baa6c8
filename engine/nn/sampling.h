// Seeded sampling of a code from logits (docs/model.md section 6).
//
//   logits' = lu + w (lc - lu)      (guidance; the caller combines, see ApplyGuidance)
//   T == 0  -> greedy: argmax, lowest index wins ties (no random draw is consumed)
//   else    -> softmax(logits / T) in double, keep the top_k most likely (0 = all), then the smallest prefix
//              whose probability reaches top_p, renormalise, draw u = (gen() >> 11) * 2^-53 and walk the
//              candidates sorted by descending probability (ties: lower index first) until the cumulative
//              probability exceeds u. The normaliser is the kept probabilities' sum: in index order when
//              top_k keeps every code and top_p == 1, else in the walk's order (the top_p threshold is
//              top_p times the top-k total). Only a prefix is sorted: the codes walked, at least 16 (all
//              top_k when top_k cuts). `logits` must not be empty.
//
// Usage:
//   std::mt19937_64 gen(seed);
//   SamplerScratch scratch(K);
//   int code = SampleCode(logits, {.temperature = 0.8f, .top_k = 40}, gen, scratch);
//
// Thread safety: pure apart from the generator and scratch, which belong to the caller.
#ifndef DANCE_ENGINE_NN_SAMPLING_H_
#define DANCE_ENGINE_NN_SAMPLING_H_

#include <cstdint>
#include <random>
#include <vector>

#include "absl/status/status.h"
#include "absl/types/span.h"

namespace dance::engine {

inline constexpr float kModelDefaultPeriodLock = -1.0f;
inline constexpr float kModelDefaultGuidance = -1.0f;
inline constexpr float kModelDefaultTopP = -1.0f;
inline constexpr float kModelDefaultMusicGuidance = -1.0f;

struct SamplingOptions {
  float temperature = 1.0f;  // >= 0; 0 = greedy
  int top_k = 0;             // >= 0; 0 = no top-k cut
  // (0, 1]; 1 = no nucleus cut, negative = the model's default (Model::default_top_p; sessions resolve it,
  // SampleCode treats it as 1).
  float top_p = kModelDefaultTopP;
  // Classifier-free style guidance weight w (<= 100); 1 = conditional logits only, negative = the model's
  // default (Model::default_guidance). The caller combines the logits (ApplyGuidance).
  float guidance = kModelDefaultGuidance;
  // Music guidance weight m (<= 100; sessions, docs/model.md section 6): l_nm + m (l - l_nm), l the
  // (style-guided) logits and l_nm the same model in its own lanes reading the music mean instead of the
  // song's music stream (PRE and the clock kept); m < 1 weakens what the song's music stream adds, 1 = off,
  // negative = the model's default (Model::default_music_guidance). SampleCode ignores it.
  float music_guidance = kModelDefaultMusicGuidance;
  // Period lock (sessions of a tempo-normalised model with dance periods; docs/model.md section 6): weight
  // (<= 100) of the logit bias toward the codes of one dance period ago; 0 = off, negative = the model's
  // default (Model::default_period_lock). SampleCode ignores it.
  float period_lock = kModelDefaultPeriodLock;
  // Crouch guard (sessions; docs/model.md section 6): after the pelvis has stayed low for longer than any
  // real dancer's crouch, the lower body samples only codes that stand. SampleCode ignores it.
  bool crouch_guard = true;
  // Foot lock (sessions; docs/model.md section 7): planted feet are held still by bending the leg
  // (engine/vq/foot_lock.h). A pose-stream clean-up after decoding; the codes do not change. SampleCode
  // ignores it.
  bool foot_lock = true;
};

// OK, or InvalidArgument naming the bad field (negative temperature, top_p outside (0, 1], ...).
absl::Status ValidateSamplingOptions(const SamplingOptions& options);

// Preallocated buffers for SampleCode, for a vocabulary of `vocab` codes.
struct SamplerScratch {
  explicit SamplerScratch(int vocab = 0) : order(vocab), probs(vocab) {}
  std::vector<int> order;
  std::vector<double> probs;
};

// logits_c[i] = logits_u[i] + w * (logits_c[i] - logits_u[i]), in place.
void ApplyGuidance(absl::Span<const float> logits_u, float w, absl::Span<float> logits_c);

// One code in [0, logits.size()). `options` must be valid.
int SampleCode(absl::Span<const float> logits, const SamplingOptions& options, std::mt19937_64& gen,
               SamplerScratch& scratch);

// The uniform draw in [0, 1) used by SampleCode: (gen() >> 11) * 2^-53.
inline double UniformDraw(std::mt19937_64& gen) { return static_cast<double>(gen() >> 11) * 0x1.0p-53; }

}  // namespace dance::engine

#endif  // DANCE_ENGINE_NN_SAMPLING_H_
