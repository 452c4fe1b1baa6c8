// A session's style mix resolved against a model: the embedding rows and normalised weights, whether it is
// "none", and what follows the top style (the metre of the bar clock, the dance period, the period lock's
// default weight, the reference tempo of a tempo-normalised model). Session parts read what they need from
// it (TimeBase the tempo and bar clock, SamplingPolicy the period, SequenceLanes the style vector).
//
// Usage:
//   absl::StatusOr<ResolvedStyle> s = ResolveStyle(model, {{"waltz", 0.7f}, {"tango", 0.3f}});
//   if (!s.ok()) { /* InvalidArgument: bad weight; NotFound: unknown style, listing the known ones */ }
//
// Thread safety: pure functions of the (immutable) model.
#ifndef DANCE_ENGINE_RUNTIME_STYLE_MIX_H_
#define DANCE_ENGINE_RUNTIME_STYLE_MIX_H_

#include <string>
#include <utility>
#include <vector>

#include "absl/status/statusor.h"
#include "engine/runtime/model.h"

namespace dance::engine {

// (name, weight) pairs as a user gives them; empty = "none".
using StyleMix = std::vector<std::pair<std::string, float>>;

struct ResolvedStyle {
  StyleMix mix;                            // as given
  std::vector<std::pair<int, float>> rows;  // embedding rows, weights normalised to sum 1 ("none" if empty)
  bool is_none = true;   // every weighted entry is "none" (an empty mix is "none")
  int top_row = 0;       // the largest-weight style (summed over repeats, first of equals; "none" if empty)
  // Tempo-normalised models only (0 otherwise): the reference tempo (BPM; weighted geometric mean of the
  // styles' references), the bar clock's period in warped frames (0 = no bar clock) and the top style's
  // dance period in warped steps (0 = unknown: no period lock).
  double reference_bpm = 0.0;
  double bar_frames = 0.0;
  double period_steps = 0.0;
  float period_lock = 0.0f;  // the top style's default period lock weight (Model::StylePeriodLock)
};

// Validates `mix` (weights finite and >= 0, not all 0; names known) and resolves it.
absl::StatusOr<ResolvedStyle> ResolveStyle(const Model& model, const StyleMix& mix);

// The row of the largest-weight style of a mix, a style named twice counting with its summed weight, the
// first of equals; unknown names are skipped; "none" (n_styles) for an empty mix.
int TopStyleRow(const Model& model, const StyleMix& mix);

// Whether every entry of a mix with a weight is "none" (an empty mix is "none").
bool StyleIsNone(const Model& model, const StyleMix& mix);

}  // namespace dance::engine

#endif  // DANCE_ENGINE_RUNTIME_STYLE_MIX_H_
