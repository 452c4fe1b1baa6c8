#include "engine/runtime/model.h"

#include <algorithm>
#include <cmath>

#include "absl/status/status.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "engine/audio/feature_layout.h"
#include "engine/audio/tempo_clock.h"
#include "engine/nn/status_macros.h"
#include "engine/vq/pose_reconstructor.h"

namespace dance::engine {
namespace {

// The pelvis height of the rest pose above its lowest joint.
float StandingHeight(const Skeleton& skeleton) {
  std::array<Eigen::Vector3f, kNumJoints> rest;
  float lowest = 0.0f;
  for (int j = 0; j < kNumJoints; ++j) {
    const int parent = skeleton.parents[j];
    rest[j] = (parent < 0 ? Eigen::Vector3f::Zero() : rest[parent]) + skeleton.offsets[j];
    lowest = std::min(lowest, rest[j].y() - rest[0].y());
  }
  return -lowest;
}

// Each code decoded kCodeHeightSteps times in a row from a fresh state (all codes in one batch): the
// height channel of the last frame.
// Each lower code decoded kCodeHeightSteps times in a row from a fresh state: its held pelvis height (the
// last frame's) and its root motion (vx, vz, yaw rate: the last step's mean).
struct HeldCodes {
  std::vector<float> height;
  std::vector<Eigen::Vector3f> motion;
};

HeldCodes HeldCodeProperties(const VqDecoder& lower) {
  const int k = lower.codebook_size();
  std::vector<int> codes(k);
  std::vector<VqDecoderState> states(k, lower.NewState());
  std::vector<VqDecoderState*> state_ptrs(k);
  for (int i = 0; i < k; ++i) {
    codes[i] = i;
    state_ptrs[i] = &states[i];
  }
  VqDecoderScratch scratch = lower.NewScratch(k);
  for (int step = 0; step + 1 < kCodeHeightSteps; ++step) lower.DecodeBatch(codes, state_ptrs, scratch);
  const auto frames = lower.DecodeBatch(codes, state_ptrs, scratch);
  const int fpc = lower.frames_per_code();
  HeldCodes held;
  held.height.resize(k);
  held.motion.resize(k);
  for (int i = 0; i < k; ++i) {
    held.height[i] = frames(kLowerHeightIndex, (i + 1) * fpc - 1);
    held.motion[i] = frames.block(kLowerHeightIndex - 3, i * fpc, 3, fpc).rowwise().mean();
  }
  return held;
}

// Reads `per` (metadata time_base.<key>, an object style name -> number) into `out` by style row: every name
// must be one of `m`'s styles and every value a number in [lo, hi] (an integer if `integer`); `range` names
// the bounds in the error message.
absl::Status ReadPerStyle(const Model& m, const nlohmann::json& per, const std::string& key, double lo, double hi,
                          bool integer, const std::string& range, std::vector<double>* out) {
  if (!per.is_object()) {
    return absl::InvalidArgumentError(absl::StrCat("weights metadata: time_base.", key, " must be an object"));
  }
  for (const auto& [name, value] : per.items()) {
    absl::StatusOr<int> row = m.StyleIndex(name);
    if (!row.ok() || *row >= static_cast<int>(m.styles().size())) {
      return absl::InvalidArgumentError(
          absl::StrCat("weights metadata: time_base.", key, " names unknown style '", name, "'"));
    }
    const bool ok_type = integer ? value.is_number_integer() : value.is_number();
    const double v = ok_type ? value.get<double>() : lo - 1.0;
    if (!(v >= lo && v <= hi)) {
      return absl::InvalidArgumentError(
          absl::StrCat("weights metadata: time_base.", key, "['", name, "'] must be in ", range));
    }
    (*out)[*row] = v;
  }
  return absl::OkStatus();
}

}  // namespace

absl::StatusOr<std::shared_ptr<const Model>> Model::FromWeights(const WeightsFile& weights) {
  DANCE_ASSIGN_OR_RETURN(SequenceModel seq, SequenceModel::Load(weights));
  DANCE_ASSIGN_OR_RETURN(VqDecoder upper, VqDecoder::Load(weights, "upper"));
  DANCE_ASSIGN_OR_RETURN(VqDecoder lower, VqDecoder::Load(weights, "lower"));
  const SeqConfig& c = seq.config();
  if (c.feature_dim != audio::kNumFeatures || (c.use_pre && c.pre_dim != audio::kPreDims)) {
    return absl::InvalidArgumentError(absl::StrCat(
        "weights file: model expects ", c.feature_dim, " features and ", c.pre_dim, " PRE dims per frame; this ",
        "engine's front end produces ", audio::kNumFeatures, " and ", audio::kPreDims));
  }
  if (upper.codebook_size() != c.codebook_size || lower.codebook_size() != c.codebook_size) {
    return absl::InvalidArgumentError("weights file: VQ codebook sizes differ from the sequence model's K");
  }
  if (upper.out_dim() != 45 || lower.out_dim() != 31 || upper.frames_per_code() != c.frames_per_step ||
      lower.frames_per_code() != c.frames_per_step) {
    return absl::InvalidArgumentError(absl::StrCat(
        "weights file: VQ decoders give ", upper.out_dim(), "/", lower.out_dim(), " dims x ",
        upper.frames_per_code(), " frames per code; expected 45/31 x ", c.frames_per_step));
  }
  std::shared_ptr<Model> m(new Model(std::move(seq), std::move(upper), std::move(lower)));
  // The encoders are optional (the controls need them; files exported before them dance without).
  absl::StatusOr<VqEncoder> upper_enc = VqEncoder::Load(weights, "upper", m->upper_.codebook());
  absl::StatusOr<VqEncoder> lower_enc = VqEncoder::Load(weights, "lower", m->lower_.codebook());
  if (upper_enc.ok() && lower_enc.ok()) {
    if (upper_enc->in_dim() != m->upper_.out_dim() || lower_enc->in_dim() != m->lower_.out_dim()) {
      return absl::InvalidArgumentError("weights file: the VQ encoders' input sizes differ from the decoders' output");
    }
    m->encoders_.emplace_back(*std::move(upper_enc));
    m->encoders_.emplace_back(*std::move(lower_enc));
  } else if (!absl::IsNotFound(upper_enc.status()) || !absl::IsNotFound(lower_enc.status())) {
    return !upper_enc.ok() && !absl::IsNotFound(upper_enc.status()) ? upper_enc.status() : lower_enc.status();
  }
  m->metadata_ = weights.metadata();
  for (int stream = 0; stream < 2; ++stream) {
    RowMatrix unit = (stream == 0 ? m->upper_ : m->lower_).codebook();
    for (Eigen::Index r = 0; r < unit.rows(); ++r) {
      const float n = unit.row(r).norm();
      if (n > 0.0f) unit.row(r) /= n;
    }
    m->unit_codebook_[stream] = std::move(unit);
  }
  DANCE_ASSIGN_OR_RETURN(m->skeleton_, Skeleton::FromMetadata(m->metadata_));
  m->standing_height_ = StandingHeight(m->skeleton_);
  HeldCodes held = HeldCodeProperties(m->lower_);
  m->lower_code_height_ = std::move(held.height);
  m->lower_code_motion_ = std::move(held.motion);
  for (int i = 0; i < static_cast<int>(m->lower_code_height_.size()); ++i) {
    if (m->lower_code_height_[i] < m->crouch_height()) m->crouched_lower_codes_.push_back(i);
  }
  if (m->crouched_lower_codes_.size() == m->lower_code_height_.size()) m->crouched_lower_codes_.clear();
  m->model_id_ = m->metadata_.value("model_id", std::string("unknown"));
  if (m->metadata_.contains("styles") && m->metadata_["styles"].is_array()) {
    for (const auto& s : m->metadata_["styles"]) {
      if (!s.is_string()) return absl::InvalidArgumentError("weights metadata: a style name is not a string");
      m->styles_.push_back(s.get<std::string>());
    }
  }
  if (static_cast<int>(m->styles_.size()) != c.n_styles) {
    return absl::InvalidArgumentError(absl::StrCat("weights metadata: ", m->styles_.size(),
                                                   " style names but n_styles = ", c.n_styles));
  }
  if (m->metadata_.contains("time_base")) {
    const nlohmann::json& tb = m->metadata_["time_base"];
    const std::string kind = tb.is_object() ? tb.value("kind", std::string()) : std::string();
    if (kind == "tempo") {
      const double ref = tb.value("reference_bpm", 0.0);
      if (!(ref >= 30.0 && ref <= 300.0)) {
        return absl::InvalidArgumentError(absl::StrCat("weights metadata: time_base.reference_bpm must be in "
                                                       "30..300 BPM, got ", ref));
      }
      m->tempo_reference_bpm_ = ref;
      m->style_reference_bpm_.assign(m->styles_.size(), ref);
      if (tb.contains("style_reference_bpm")) {
        DANCE_RETURN_IF_ERROR(ReadPerStyle(*m, tb["style_reference_bpm"], "style_reference_bpm", 30.0, 300.0,
                                           false, "30..300 BPM", &m->style_reference_bpm_));
      }
      if (tb.contains("bar_clock")) {
        const nlohmann::json& bc = tb["bar_clock"];
        auto beats_of = [](const nlohmann::json& v) { return v.is_number_integer() ? v.get<int>() : 0; };
        const int beats = bc.is_object() && bc.contains("beats_per_bar") ? beats_of(bc["beats_per_bar"]) : 0;
        if (beats < 1 || beats > 16) {
          return absl::InvalidArgumentError(
              "weights metadata: time_base.bar_clock.beats_per_bar must be an integer in 1..16");
        }
        m->beats_per_bar_ = beats;
        m->style_beats_per_bar_.assign(m->styles_.size(), beats);
        if (bc.contains("style_beats_per_bar")) {
          std::vector<double> per(m->styles_.size(), beats);
          DANCE_RETURN_IF_ERROR(ReadPerStyle(*m, bc["style_beats_per_bar"], "bar_clock.style_beats_per_bar", 1.0,
                                             16.0, true, "1..16", &per));
          m->style_beats_per_bar_.assign(per.begin(), per.end());
        }
      }
      if (tb.contains("fold_tempo")) {
        if (!tb["fold_tempo"].is_boolean()) {
          return absl::InvalidArgumentError("weights metadata: time_base.fold_tempo must be true or false");
        }
        m->fold_tempo_ = tb["fold_tempo"].get<bool>();
      }
      if (tb.contains("dance_period_beats")) {
        std::vector<double> per(m->styles_.size(), 0.0);
        DANCE_RETURN_IF_ERROR(ReadPerStyle(*m, tb["dance_period_beats"], "dance_period_beats", 0.5, 16.0, false,
                                           "0.5..16 beats", &per));
        if (!tb["dance_period_beats"].empty()) m->dance_period_beats_ = std::move(per);
      }
      if (tb.contains("period_lock")) {
        const double lock = tb["period_lock"].is_number() ? tb["period_lock"].get<double>() : -1.0;
        if (!(lock >= 0.0 && lock <= 100.0)) {
          return absl::InvalidArgumentError("weights metadata: time_base.period_lock must be a number in 0..100");
        }
        if (lock > 0.0 && m->dance_period_beats_.empty()) {
          return absl::InvalidArgumentError("weights metadata: time_base.period_lock needs dance_period_beats");
        }
        m->default_period_lock_ = static_cast<float>(lock);
      }
      m->style_period_lock_.assign(m->styles_.size(), m->default_period_lock_);
      if (tb.contains("style_period_lock")) {
        // {style: B_s, ...}: the lock weight of sessions whose top style is s (others: period_lock).
        std::vector<double> per(m->styles_.size(), m->default_period_lock_);
        DANCE_RETURN_IF_ERROR(
            ReadPerStyle(*m, tb["style_period_lock"], "style_period_lock", 0.0, 100.0, false, "0..100", &per));
        if (m->dance_period_beats_.empty() && std::any_of(per.begin(), per.end(), [](double b) { return b > 0.0; })) {
          return absl::InvalidArgumentError("weights metadata: time_base.style_period_lock needs dance_period_beats");
        }
        m->style_period_lock_.assign(per.begin(), per.end());
      }
      if (tb.contains("period_lock_sharpness")) {
        const nlohmann::json& sh = tb["period_lock_sharpness"];
        const double v = sh.is_number() ? sh.get<double>() : 0.0;
        if (!(v >= 1.0 && v <= 100.0)) {
          return absl::InvalidArgumentError("weights metadata: time_base.period_lock_sharpness must be a number in 1..100");
        }
        m->period_lock_sharpness_ = static_cast<float>(v);
      }
      if (tb.contains("period_lock_periods")) {
        // {"upper": n, "lower": n}: each stream's lock repeats the codes of n dance periods back (1..4).
        const nlohmann::json& pp = tb["period_lock_periods"];
        if (!pp.is_object()) {
          return absl::InvalidArgumentError("weights metadata: time_base.period_lock_periods must be an object");
        }
        for (const auto& [name, value] : pp.items()) {
          const int stream = name == "upper" ? 0 : name == "lower" ? 1 : -1;
          if (stream < 0) {
            return absl::InvalidArgumentError(absl::StrCat(
                "weights metadata: time_base.period_lock_periods names unknown stream '", name,
                "' (expected upper, lower)"));
          }
          const int n = value.is_number_integer() ? value.get<int>() : 0;
          if (n < 1 || n > kMaxPeriodLockPeriods) {
            return absl::InvalidArgumentError(absl::StrCat("weights metadata: time_base.period_lock_periods['", name,
                                                           "'] must be an integer in 1..", kMaxPeriodLockPeriods));
          }
          m->period_lock_periods_[stream] = n;
        }
      }
    } else if (kind != "fixed") {
      return absl::InvalidArgumentError(
          absl::StrCat("weights metadata: unknown time_base '", tb.dump(), "' (expected kind fixed or tempo)"));
    }
  }
  if (m->metadata_.contains("sampling")) {
    const nlohmann::json& sm = m->metadata_["sampling"];
    if (!sm.is_object()) return absl::InvalidArgumentError("weights metadata: sampling must be an object");
    // Each key optional; a present one must be a number with lo < x <= hi (lo itself allowed if closed).
    auto read = [&](const char* key, double lo, bool closed, double hi, const char* range, float* out) {
      if (!sm.contains(key)) return absl::OkStatus();
      const double v = sm[key].is_number() ? sm[key].get<double>() : std::nan("");
      if (!((v > lo || (closed && v == lo)) && v <= hi)) {
        return absl::InvalidArgumentError(absl::StrCat("weights metadata: sampling.", key, " must be a number in ", range));
      }
      *out = static_cast<float>(v);
      return absl::OkStatus();
    };
    DANCE_RETURN_IF_ERROR(read("guidance", 0.0, true, 100.0, "0..100", &m->default_guidance_));
    DANCE_RETURN_IF_ERROR(read("music_guidance", 0.0, true, 100.0, "0..100", &m->default_music_guidance_));
    if (sm.contains("music_guidance_features")) {
      const nlohmann::json& ranges = sm["music_guidance_features"];
      const std::string bad = absl::StrCat("weights metadata: sampling.music_guidance_features must be a non-empty "
                                           "list of [begin, end] feature columns with 0 <= begin < end <= ",
                                           audio::kNumFeatures);
      if (!ranges.is_array() || ranges.empty()) return absl::InvalidArgumentError(bad);
      for (const nlohmann::json& r : ranges) {
        if (!r.is_array() || r.size() != 2 || !r[0].is_number_integer() || !r[1].is_number_integer()) {
          return absl::InvalidArgumentError(bad);
        }
        const int b = r[0].get<int>(), e = r[1].get<int>();
        if (!(0 <= b && b < e && e <= audio::kNumFeatures)) return absl::InvalidArgumentError(bad);
        m->music_guidance_features_.emplace_back(b, e);
      }
    }
    DANCE_RETURN_IF_ERROR(read("top_p", 0.0, false, 1.0, "(0, 1]", &m->default_top_p_));
  }
  return std::shared_ptr<const Model>(std::move(m));
}

absl::StatusOr<int> Model::StyleIndex(const std::string& name) const {
  if (name == "none" || name.empty()) return config().n_styles;
  for (size_t i = 0; i < styles_.size(); ++i) {
    if (styles_[i] == name) return static_cast<int>(i);
  }
  return absl::NotFoundError(
      absl::StrCat("unknown style '", name, "'; this model knows: ", absl::StrJoin(styles_, ", "), ", none"));
}

double Model::LatencyMs() const {
  const double fixed = config().music_lookahead_steps * 1000.0 * config().frames_per_step / audio::kFrameRate;
  // Warped steps last 1 / rate real frames; the slowest rate the clock can pick is 1 / (sqrt 2 (1 + h)).
  if (tempo_reference_bpm_ > 0.0) return fixed * std::sqrt(2.0) * (1.0 + audio::TempoClockOptions().octave_hysteresis);
  return fixed;
}

absl::StatusOr<std::shared_ptr<const Model>> LoadModel(const std::string& path) {
  DANCE_ASSIGN_OR_RETURN(WeightsFile weights, WeightsFile::Load(path));
  absl::StatusOr<std::shared_ptr<const Model>> model = Model::FromWeights(weights);
  if (!model.ok()) {
    return absl::Status(model.status().code(), absl::StrCat(model.status().message(), " (", path, ")"));
  }
  return model;
}

}  // namespace dance::engine
