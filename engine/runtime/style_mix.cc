#include "engine/runtime/style_mix.h"

#include <algorithm>
#include <cmath>

#include "absl/strings/str_cat.h"
#include "engine/audio/feature_layout.h"
#include "engine/audio/tempo_clock.h"
#include "engine/nn/status_macros.h"

namespace dance::engine {

absl::StatusOr<ResolvedStyle> ResolveStyle(const Model& model, const StyleMix& mix) {
  ResolvedStyle r;
  double total = 0.0;
  for (const auto& [name, weight] : mix) {
    if (!(weight >= 0.0f) || !std::isfinite(weight)) {
      return absl::InvalidArgumentError(absl::StrCat("style '", name, "': weight must be finite and >= 0, got ",
                                                     weight));
    }
    DANCE_ASSIGN_OR_RETURN(int row, model.StyleIndex(name));
    r.rows.emplace_back(row, weight);
    total += weight;
  }
  if (r.rows.empty()) {
    r.rows.emplace_back(model.config().n_styles, 1.0f);
    total = 1.0;
  }
  if (!(total > 0.0)) return absl::InvalidArgumentError("style weights sum to 0");
  for (auto& row : r.rows) row.second = static_cast<float>(row.second / total);
  r.mix = mix;
  r.is_none = StyleIsNone(model, mix);
  r.top_row = TopStyleRow(model, mix);
  r.period_lock = model.StylePeriodLock(r.top_row);
  if (model.tempo_reference_bpm() > 0.0) {
    // Each style is learned at its own typical tempo, so a song's octave folds consistently whatever its
    // exact tempo (docs/model.md section 1).
    double log_ref = 0.0;
    for (const auto& [row, weight] : r.rows) log_ref += weight * std::log(model.StyleReferenceBpm(row));
    r.reference_bpm = std::exp(log_ref);
    if (model.bar_clock()) r.bar_frames = audio::BarClockFrames(model.StyleBeatsPerBar(r.top_row), r.reference_bpm);
    // One dance period in warped steps: beats x (1800 / R warped frames per beat) / frames per step.
    r.period_steps = model.StyleDancePeriodBeats(r.top_row) * 60.0 * audio::kFrameRate / r.reference_bpm /
                     model.config().frames_per_step;
  }
  return r;
}

int TopStyleRow(const Model& model, const StyleMix& mix) {
  // Rows in order of first appearance, so the first of equals wins.
  std::vector<std::pair<int, double>> totals;
  for (const auto& [name, weight] : mix) {
    const absl::StatusOr<int> row = model.StyleIndex(name);
    if (!row.ok()) continue;
    auto it = std::find_if(totals.begin(), totals.end(), [&](const auto& t) { return t.first == *row; });
    if (it == totals.end()) {
      totals.emplace_back(*row, weight);
    } else {
      it->second += weight;
    }
  }
  int top = model.config().n_styles;
  double best = -1.0;
  for (const auto& [row, total] : totals) {
    if (total > best) {
      best = total;
      top = row;
    }
  }
  return top;
}

bool StyleIsNone(const Model& model, const StyleMix& mix) {
  return std::all_of(mix.begin(), mix.end(), [&](const auto& e) {
    const absl::StatusOr<int> row = model.StyleIndex(e.first);
    return e.second == 0.0f || (row.ok() && *row == model.config().n_styles);
  });
}

}  // namespace dance::engine
