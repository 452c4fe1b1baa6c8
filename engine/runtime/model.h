// A loaded dance model: the sequence model, both VQ decoders, the skeleton and the style names, read and
// validated from one `.dncw` file. Immutable after LoadModel and shared by every Session
// (std::shared_ptr<const Model>); thread-safe to read.
//
// Usage:
//   absl::StatusOr<std::shared_ptr<const Model>> model = LoadModel("models/default.dncw");
//   if (!model.ok()) { /* NotFound, DataLoss (corrupt), InvalidArgument (mismatched) */ }
#ifndef DANCE_ENGINE_RUNTIME_MODEL_H_
#define DANCE_ENGINE_RUNTIME_MODEL_H_

#include <memory>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "engine/model/sequence_model.h"
#include "engine/vq/skeleton.h"
#include "engine/vq/vq_decoder.h"

namespace dance::engine {

class Model {
 public:
  // Builds a model from validated weights (LoadModel = WeightsFile::Load + this).
  static absl::StatusOr<std::shared_ptr<const Model>> FromWeights(const WeightsFile& weights);

  const std::string& model_id() const { return model_id_; }
  const SequenceModel& sequence() const { return sequence_; }
  const SeqConfig& config() const { return sequence_.config(); }
  const VqDecoder& upper_decoder() const { return upper_; }
  const VqDecoder& lower_decoder() const { return lower_; }
  const Skeleton& skeleton() const { return skeleton_; }
  // Style names in embedding-row order (size n_styles); "none" is implicit (row n_styles).
  const std::vector<std::string>& styles() const { return styles_; }
  // Row of style `name`, n_styles for "none", or NotFound listing the known styles.
  absl::StatusOr<int> StyleIndex(const std::string& name) const;
  // Declared latency: music_lookahead_steps * 133.3 ms (the feature extractor's lookahead is 0).
  double LatencyMs() const;
  // Reference tempo (BPM) of a model that dances in tempo-normalised time (metadata
  // "time_base": {"kind": "tempo", "reference_bpm": R, "style_reference_bpm": {style: R_s, ...}});
  // 0 for a fixed-rate model.
  double tempo_reference_bpm() const { return tempo_reference_bpm_; }
  // The reference of style row `row` (R_s, or R for styles without one and for "none").
  double StyleReferenceBpm(int row) const {
    return row >= 0 && row < static_cast<int>(style_reference_bpm_.size()) ? style_reference_bpm_[row]
                                                                            : tempo_reference_bpm_;
  }
  // The bar clock of a tempo-normalised model (metadata "time_base": {..., "bar_clock": {"beats_per_bar":
  // B, "style_beats_per_bar": {style: B_s, ...}}}): if present, the `bar_phase` features of warped frame j
  // are replaced by the phase of a metronome in warped time, frac(j / L), L = beats * 1800 / R warped
  // frames (docs/model.md section 1). 0 = no bar clock (the beat tracker's bar phase is used).
  int StyleBeatsPerBar(int row) const {
    return row >= 0 && row < static_cast<int>(style_beats_per_bar_.size()) ? style_beats_per_bar_[row]
                                                                             : beats_per_bar_;
  }
  bool bar_clock() const { return beats_per_bar_ > 0; }
  // The header metadata, for tools that copy it (feature config, training info).
  const nlohmann::json& metadata() const { return metadata_; }

 private:
  Model(SequenceModel seq, VqDecoder upper, VqDecoder lower)
      : sequence_(std::move(seq)), upper_(std::move(upper)), lower_(std::move(lower)) {}

  std::string model_id_;
  SequenceModel sequence_;
  VqDecoder upper_;
  VqDecoder lower_;
  Skeleton skeleton_;
  std::vector<std::string> styles_;
  nlohmann::json metadata_;
  double tempo_reference_bpm_ = 0.0;
  std::vector<double> style_reference_bpm_;  // per style row (n_styles)
  int beats_per_bar_ = 0;                     // bar clock: default beats per bar (0 = none)
  std::vector<int> style_beats_per_bar_;      // per style row (n_styles)
};

// Loads and validates `path`.
absl::StatusOr<std::shared_ptr<const Model>> LoadModel(const std::string& path);

}  // namespace dance::engine

#endif  // DANCE_ENGINE_RUNTIME_MODEL_H_
