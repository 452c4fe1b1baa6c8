// A loaded dance model: the sequence model, both VQ decoders, the skeleton and the style names, read and
// validated from one `.dncw` file. Immutable after LoadModel and shared by every Session
// (std::shared_ptr<const Model>); thread-safe to read.
//
// Usage:
//   absl::StatusOr<std::shared_ptr<const Model>> model = LoadModel("models/default.dncw");
//   if (!model.ok()) { /* NotFound, DataLoss (corrupt), InvalidArgument (mismatched) */ }
#ifndef DANCE_ENGINE_RUNTIME_MODEL_H_
#define DANCE_ENGINE_RUNTIME_MODEL_H_

#include <array>
#include <memory>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "engine/model/sequence_model.h"
#include "engine/vq/pose_encoder.h"
#include "engine/vq/skeleton.h"
#include "engine/vq/vq_decoder.h"

namespace dance::engine {

// A pose is crouched when its pelvis is below this fraction of the standing height (0.79 m of 0.956 m for the
// shipped skeleton; real Tang dancers are below 0.8 m in 0.9 % of frames). Used by the crouch guard
// (session.h).
inline constexpr float kCrouchHeightFraction = 0.83f;

// Steps a lower-body code is repeated from a fresh decoder state to measure its held pelvis height: the
// decoder's fixed point (measured on the shipped model: the heights after 4 / 8 / 12 steps differ from those
// after 32 by up to 81 / 18 / 1.7 mm, after 16 by < 0.05 mm).
inline constexpr int kCodeHeightSteps = 16;

// The period lock's kernel exp((s - 1) x sharpness) over a code's cosine similarity s to the target, for
// models without time_base.period_lock_sharpness: 1 for the target code itself, 0.37 at s = 0.95 (the
// typical nearest code of the shipped codebooks), 0.007 at s = 0.75.
constexpr float kDefaultPeriodLockSharpness = 20.0f;
// The most dance periods a stream's period lock may reach back (time_base.period_lock_periods).
inline constexpr int kMaxPeriodLockPeriods = 4;

class Model {
 public:
  // Builds a model from validated weights (LoadModel = WeightsFile::Load + this).
  static absl::StatusOr<std::shared_ptr<const Model>> FromWeights(const WeightsFile& weights);

  const std::string& model_id() const { return model_id_; }
  const SequenceModel& sequence() const { return sequence_; }
  const SeqConfig& config() const { return sequence_.config(); }
  const VqDecoder& upper_decoder() const { return upper_; }
  const VqDecoder& lower_decoder() const { return lower_; }
  // The VQ-VAE encoders (given motion to codes; the controls), if the file has them (metadata
  // vq.<part>.encoder_ops); null otherwise.
  const VqEncoder* upper_encoder() const { return encoders_.empty() ? nullptr : &encoders_[0]; }
  const VqEncoder* lower_encoder() const { return encoders_.empty() ? nullptr : &encoders_[1]; }
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
  // The tempo fold of a tempo-normalised model (metadata "time_base": {..., "fold_tempo": true}): the
  // `tempogram` and `tempo` features of warped frame j are shown as if the song played at the folded
  // reference tempo (audio::FoldTempoFeatures with the source frame's clock rate; docs/model.md section 1),
  // so the model sees a style's songs at one tempo whatever their own. false = the features as extracted.
  bool fold_tempo() const { return fold_tempo_; }
  // The dance period of style row `row` in beats, measured on the training dances (metadata "time_base":
  // {..., "dance_period_beats": {style: beats, ...}}; the waltzes here move once per 3-beat bar, cha-cha and
  // rumba every 2 beats); 0 = not known (styles without one, "none", models without the key). Sessions use
  // it for the period lock (SamplingOptions::period_lock).
  double StyleDancePeriodBeats(int row) const {
    return row >= 0 && row < static_cast<int>(dance_period_beats_.size()) ? dance_period_beats_[row] : 0.0;
  }
  bool has_dance_periods() const { return !dance_period_beats_.empty(); }
  // The period lock weight sessions use when SamplingOptions::period_lock is negative (metadata
  // "time_base": {..., "period_lock": B}, which needs dance_period_beats); 0 = off (models without it).
  float default_period_lock() const { return default_period_lock_; }
  // The period lock weight of sessions whose top style is row `row` (metadata "time_base": {...,
  // "style_period_lock": {style: B_s, ...}}, each 0..100; styles not named, "none" and rows out of range:
  // default_period_lock()). The waltzes here follow the tempo unlocked (docs/research-log.md).
  float StylePeriodLock(int row) const {
    return row >= 0 && row < static_cast<int>(style_period_lock_.size()) ? style_period_lock_[row]
                                                                           : default_period_lock_;
  }
  // How many dance periods back each stream's period lock reaches (metadata "time_base": {...,
  // "period_lock_periods": {"upper": n, "lower": n}}, integers 1..kMaxPeriodLockPeriods; default 1 each):
  // the lag is n x the dance period in whole steps (Session::lock_lag). Stream 0 upper, 1 lower. Two for
  // the lower body repeats a two-period figure (a waltz's box step is two bars, one led by each foot).
  int period_lock_periods(int stream) const { return period_lock_periods_[stream]; }
  // The sharpness of the period lock's kernel over code similarity (metadata "time_base": {...,
  // "period_lock_sharpness": S}, 1..100; default kDefaultPeriodLockSharpness). Lower spreads the lock's
  // pull from the target code to its neighbours in the codebook (docs/model.md section 6).
  float period_lock_sharpness() const { return period_lock_sharpness_; }
  // The style guidance weight sessions use when SamplingOptions::guidance is negative (metadata
  // "sampling": {"guidance": W}, 0..100); 1 = off (models without it).
  float default_guidance() const { return default_guidance_; }
  // The music guidance weight sessions use when SamplingOptions::music_guidance is negative (metadata
  // "sampling": {"music_guidance": M}, 0..100); 1 = off (models without it).
  float default_music_guidance() const { return default_music_guidance_; }
  // The per-frame feature columns [begin, end) music guidance's lanes replace by the music mean (metadata
  // "sampling": {"music_guidance_features": [[b, e], ...]}, the columns the model's music dropout
  // replaced); empty = every column (the whole token is the mean).
  const std::vector<std::pair<int, int>>& music_guidance_features() const { return music_guidance_features_; }
  // The nucleus cut sessions use when SamplingOptions::top_p is negative (metadata "sampling":
  // {"top_p": P}, (0, 1]); 1 = no cut (models without it).
  float default_top_p() const { return default_top_p_; }
  // The codebooks with unit-length rows, (K, code_dim): stream 0 upper, 1 lower (cosine similarity of codes).
  const RowMatrix& unit_codebook(int stream) const { return unit_codebook_[stream]; }
  // Pelvis height (metres) of each lower-body code held still: the code decoded kCodeHeightSteps times in a
  // row from a fresh decoder state, the height channel of the last frame (the crouch guard's table;
  // docs/model.md section 6).
  const std::vector<float>& lower_code_height() const { return lower_code_height_; }
  // Root motion of each lower-body code held the same way: (vx, vz) metres per (warped) frame in the
  // body's facing frame and the yaw rate in radians per frame (the trajectory control ranks codes by it).
  const std::vector<Eigen::Vector3f>& lower_code_motion() const { return lower_code_motion_; }
  // The pelvis height of the skeleton's rest pose (standing straight) above its lowest joint, metres.
  float standing_height() const { return standing_height_; }
  // Below this pelvis height a pose is crouched: kCrouchHeightFraction x standing_height().
  float crouch_height() const { return kCrouchHeightFraction * standing_height_; }
  // The lower-body codes whose held pose is crouched (lower_code_height < crouch_height), ascending; the
  // crouch guard excludes them. Empty if every code is (no code would be left to sample).
  const std::vector<int>& crouched_lower_codes() const { return crouched_lower_codes_; }
  // The header metadata, for tools that copy it (feature config, training info).
  const nlohmann::json& metadata() const { return metadata_; }

 private:
  Model(SequenceModel seq, VqDecoder upper, VqDecoder lower)
      : sequence_(std::move(seq)), upper_(std::move(upper)), lower_(std::move(lower)) {}

  std::string model_id_;
  SequenceModel sequence_;
  VqDecoder upper_;
  VqDecoder lower_;
  std::vector<VqEncoder> encoders_;  // upper, lower; empty if the file has none
  Skeleton skeleton_;
  std::vector<std::string> styles_;
  nlohmann::json metadata_;
  double tempo_reference_bpm_ = 0.0;
  std::vector<double> style_reference_bpm_;  // per style row (n_styles)
  int beats_per_bar_ = 0;                     // bar clock: default beats per bar (0 = none)
  bool fold_tempo_ = false;                   // time_base.fold_tempo
  std::vector<int> style_beats_per_bar_;      // per style row (n_styles)
  std::vector<double> dance_period_beats_;    // per style row (n_styles); empty = none
  float default_period_lock_ = 0.0f;
  std::vector<float> style_period_lock_;      // per style row (n_styles)
  std::array<int, 2> period_lock_periods_ = {1, 1};  // upper, lower
  float period_lock_sharpness_ = kDefaultPeriodLockSharpness;
  float default_guidance_ = 1.0f;
  float default_music_guidance_ = 1.0f;
  std::vector<std::pair<int, int>> music_guidance_features_;
  float default_top_p_ = 1.0f;
  std::array<RowMatrix, 2> unit_codebook_;    // upper, lower
  std::vector<float> lower_code_height_;      // (K)
  std::vector<Eigen::Vector3f> lower_code_motion_;  // (K) vx, vz, yaw rate
  float standing_height_ = 0.0f;
  std::vector<int> crouched_lower_codes_;
};


// Loads and validates `path`.
absl::StatusOr<std::shared_ptr<const Model>> LoadModel(const std::string& path);

}  // namespace dance::engine

#endif  // DANCE_ENGINE_RUNTIME_MODEL_H_
