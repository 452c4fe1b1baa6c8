#include "engine/runtime/session.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <tuple>

#include "absl/strings/str_cat.h"
#include "engine/nn/status_macros.h"

namespace dance::engine {
namespace {

constexpr int kFeatureDims = audio::kNumFeatures;
constexpr int kPreDims = audio::kPreDims;
// The furthest the lock can reach back: kMaxPeriodLockPeriods (4) periods of 16 beats at 30 BPM, 240 steps each.
constexpr size_t kMaxCodeHistory = 1024;
static_assert(kMaxCodeHistory >= kMaxPeriodLockPeriods * 240);

}  // namespace

Session::Session(std::shared_ptr<const Model> model, const SessionOptions& options)
    : model_(std::move(model)),
      options_(options),
      sampling_(options.sampling),
      generator_(options.seed),
      reconstructor_(model_->skeleton()),
      foot_lock_(model_->skeleton()),
      sampler_(model_->config().codebook_size) {}

Session::~Session() = default;

absl::StatusOr<std::unique_ptr<Session>> Session::Create(std::shared_ptr<const Model> model,
                                                         const SessionOptions& options) {
  if (model == nullptr) return absl::InvalidArgumentError("session: no model");
  DANCE_RETURN_IF_ERROR(ValidateSamplingOptions(options.sampling));
  audio::AudioFrontEndOptions fe_options;
  fe_options.sample_rate = options.input_sample_rate;
  fe_options.channels = options.input_channels;
  DANCE_ASSIGN_OR_RETURN(std::unique_ptr<audio::AudioFrontEnd> front_end, audio::AudioFrontEnd::Create(fe_options));
  std::unique_ptr<Session> s(new Session(std::move(model), options));
  s->front_end_ = std::move(front_end);
  const SequenceModel& seq = s->model_->sequence();
  const int k = seq.config().codebook_size;
  s->cond_ = seq.NewState();
  s->uncond_ = seq.NewState();
  s->upper_code_ = s->lower_code_ = k;  // BOS
  s->upper_state_ = s->model_->upper_decoder().NewState();
  s->lower_state_ = s->model_->lower_decoder().NewState();
  s->guided_u_.resize(k);
  s->guided_l_.resize(k);
  s->music_u_.resize(k);
  s->music_l_.resize(k);
  s->warp_ = s->NewWarpState();
  DANCE_RETURN_IF_ERROR(s->ApplyStyle(options.style));
  return s;
}

WarpState Session::NewWarpState() const {
  WarpState w;
  w.clock = audio::TempoClock({.reference_bpm = warped() ? style_reference_bpm_ : 120.0});
  // The first decoded period is period 1; real frames start being emitted at the same index.
  w.first_pose = model_->config().frames_per_step;
  w.next_output = model_->config().frames_per_step;
  return w;
}

absl::Status Session::ApplyStyle(const std::vector<std::pair<std::string, float>>& style) {
  std::vector<std::pair<int, float>> rows;
  double total = 0.0;
  for (const auto& [name, weight] : style) {
    if (!(weight >= 0.0f) || !std::isfinite(weight)) {
      return absl::InvalidArgumentError(absl::StrCat("style '", name, "': weight must be finite and >= 0, got ",
                                                     weight));
    }
    DANCE_ASSIGN_OR_RETURN(int row, model_->StyleIndex(name));
    rows.emplace_back(row, weight);
    total += weight;
  }
  if (rows.empty()) {
    rows.emplace_back(model_->config().n_styles, 1.0f);
    total = 1.0;
  }
  if (!(total > 0.0)) return absl::InvalidArgumentError("style weights sum to 0");
  for (auto& r : rows) r.second = static_cast<float>(r.second / total);
  // (Guidance is skipped while the style is "none": the conditional lane is then the unconditional one,
  // and PrepareLanes starts the unconditional lane from it when a style comes.)
  style_is_none_ = StyleIsNone(style);
  const Eigen::VectorXf sv = model_->sequence().StyleVector(rows);
  model_->sequence().SetStyle(sv, &cond_);
  if (!music_cond_.keys.empty()) model_->sequence().SetStyle(sv, &music_cond_);
  style_ = style;
  // The metre, dance period and period lock weight follow the style with the largest weight (TopStyleRow).
  const int top = TopStyleRow(style);
  style_period_lock_ = model_->StylePeriodLock(top);
  if (warped()) {
    // The style's reference tempo (weighted geometric mean for a mix): each style is learned at its own
    // typical tempo, so a song's octave folds consistently whatever its exact tempo (docs/model.md s. 1).
    double log_ref = 0.0;
    for (const auto& [row, weight] : rows) log_ref += weight * std::log(model_->StyleReferenceBpm(row));
    const double ref = std::exp(log_ref);
    if (ref != style_reference_bpm_) {
      style_reference_bpm_ = ref;
      warp_.clock.SetReference(ref);
    }
    if (model_->bar_clock()) bar_frames_ = audio::BarClockFrames(model_->StyleBeatsPerBar(top), ref);
    // One dance period in warped steps: beats x (1800 / R warped frames per beat) / frames per step.
    period_steps_ = model_->StyleDancePeriodBeats(top) * 60.0 * audio::kFrameRate / ref /
                    model_->config().frames_per_step;
  }
  return absl::OkStatus();
}

int Session::TopStyleRow(const std::vector<std::pair<std::string, float>>& style) const {
  // A style named more than once counts with its summed weight (as in the style vector); rows in order of
  // first appearance, so the first of equals wins.
  std::vector<std::pair<int, double>> totals;
  for (const auto& [name, weight] : style) {
    const absl::StatusOr<int> row = model_->StyleIndex(name);
    if (!row.ok()) continue;
    auto it = std::find_if(totals.begin(), totals.end(), [&](const auto& t) { return t.first == *row; });
    if (it == totals.end()) {
      totals.emplace_back(*row, weight);
    } else {
      it->second += weight;
    }
  }
  int top = model_->config().n_styles;  // "none" (also an empty mix)
  double best = -1.0;
  for (const auto& [row, total] : totals) {
    if (total > best) {
      best = total;
      top = row;
    }
  }
  return top;
}

bool Session::StyleIsNone(const std::vector<std::pair<std::string, float>>& style) const {
  return std::all_of(style.begin(), style.end(), [&](const auto& e) {
    const absl::StatusOr<int> row = model_->StyleIndex(e.first);
    return e.second == 0.0f || (row.ok() && *row == model_->config().n_styles);
  });
}

absl::Status Session::SetStyle(const std::vector<std::pair<std::string, float>>& style) { return ApplyStyle(style); }

absl::Status Session::SetSampling(const SamplingOptions& sampling) {
  DANCE_RETURN_IF_ERROR(ValidateSamplingOptions(sampling));
  sampling_ = sampling;  // lanes switched on start at the next step (PrepareLanes)
  return absl::OkStatus();
}

namespace {

// `to` continues from `from`'s history (step, KV caches, Mamba states) with the style factors `style_bias`.
void StartLane(const SequenceState& from, const Eigen::MatrixXf& style_bias, SequenceState* to) {
  Eigen::MatrixXf bias = style_bias;  // may be to's own
  *to = from;
  to->style_bias = std::move(bias);
}

}  // namespace

const float* Session::MeanMusicToken(const float* music) {
  const Eigen::VectorXf& mean = model_->sequence().music_mean();
  const auto& ranges = model_->music_guidance_features();
  if (ranges.empty()) return mean.data();
  mean_token_.assign(music, music + mean.size());
  for (int f = 0; f < model_->config().frames_per_step; ++f) {
    const int row = f * kFeatureDims;
    for (const auto& [b, e] : ranges) {
      std::copy(mean.data() + row + b, mean.data() + row + e, mean_token_.begin() + row + b);
    }
  }
  return mean_token_.data();
}

void Session::PrepareLanes() {
  const bool uncond = uses_guidance();
  const bool music = uses_music_guidance();
  const bool music_uncond = uncond && music;
  // uncond_ always holds style "none"'s factors (it never takes a style).
  if (uncond && !uncond_live_) StartLane(cond_, uncond_.style_bias, &uncond_);
  // The "none" lane on the music mean continues the one that read the music mean if there was one (style
  // guidance switched on), else the "none" lane on the music (music guidance switched on).
  if (music_uncond && !music_uncond_live_) {
    StartLane(music_cond_live_ ? music_cond_ : uncond_, uncond_.style_bias, &music_uncond_);
  }
  if (music && !music_cond_live_) StartLane(cond_, cond_.style_bias, &music_cond_);
  uncond_live_ = uncond;
  music_cond_live_ = music;
  music_uncond_live_ = music_uncond;
}

absl::Status Session::PushAudio(absl::Span<const float> interleaved) {
  if (ended_) return absl::FailedPreconditionError("session: audio pushed after EndOfAudio");
  DANCE_RETURN_IF_ERROR(front_end_->PushFloat(interleaved));
  CollectFrames();
  return absl::OkStatus();
}

absl::Status Session::PushAudioInt16(absl::Span<const int16_t> interleaved) {
  if (ended_) return absl::FailedPreconditionError("session: audio pushed after EndOfAudio");
  DANCE_RETURN_IF_ERROR(front_end_->PushInt16(interleaved));
  CollectFrames();
  return absl::OkStatus();
}

void Session::EndOfAudio() {
  if (ended_) return;
  // The dance covers every period the audio reaches into: count the 24 kHz samples received, round up to
  // whole periods, and feed silence so the front end completes them (the extra frames are not used).
  const int rate = options_.input_sample_rate;
  const int64_t in_frames = front_end_->input_frames();
  const int64_t samples24 = (in_frames * audio::kSampleRate + rate - 1) / rate;
  const int64_t period = static_cast<int64_t>(audio::kHopSamples) * model_->config().frames_per_step;
  const int64_t periods = (samples24 + period - 1) / period;
  frames_limit_ = periods * model_->config().frames_per_step;
  // Warped steps read past the last emitted real frame (the poses of real frame m come from warped
  // frames up to ceil(W_m) and the model reads one period of music behind them): pad extra real frames,
  // enough at the slowest clock rate (~0.65 warped frames per real frame).
  if (warped()) warp_.output_limit = frames_limit_;  // before the padding's frames reach EmitWarpedFrames
  const int64_t extra_frames =
      warped() ? 16 + 8 * (model_->config().music_lookahead_steps + 1) * model_->config().frames_per_step : 0;
  const int64_t missing24 =
      std::max<int64_t>(0, (frames_limit_ + extra_frames) * audio::kHopSamples - samples24);
  const int64_t pad = (missing24 + audio::kHopSamples) * rate / audio::kSampleRate + rate / 10 +
                      front_end_->BufferingSamples();
  std::vector<float> silence(static_cast<size_t>(pad) * options_.input_channels, 0.0f);
  front_end_->PushFloat(silence).IgnoreError();  // length is a multiple of the channel count
  front_end_->Flush().IgnoreError();
  CollectFrames();
  ended_ = true;
  if (warped()) {
    // Real frames [4, frames_limit_) are emitted; the last one needs decoded warped frames up to
    // ceil(W), i.e. periods 1..K with 4 (K + 1) > ceil(W), and K steps read music up to 4 (K + s).
    const SeqConfig& c = model_->config();
    const int64_t last = frames_limit_ - 1;
    if (last < warp_.next_output) return;  // nothing more to emit
    const double w_last = warp_.starts[last - warp_.next_output];
    const int64_t needed_decoded = static_cast<int64_t>(std::ceil(w_last)) + 1;
    const int64_t periods_needed = (needed_decoded + c.frames_per_step - 1) / c.frames_per_step;  // K + 1
    warp_.warped_limit = std::min<int64_t>(warp_.clock.warped_frames(),
                                           (periods_needed - 1 + c.music_lookahead_steps) * c.frames_per_step);
    EmitWarpedFrames();
  }
}

void Session::CollectFrames() {
  front_end_->PopFrames(&popped_);
  const int64_t n = popped_.frames();
  if (n == 0) return;
  pending_features_.insert(pending_features_.end(), popped_.features.begin(), popped_.features.end());
  pending_pre_.insert(pending_pre_.end(), popped_.pre.begin(), popped_.pre.end());
  if (warped()) {
    for (int64_t i = 0; i < n; ++i) {
      const float tempo = popped_.features[i * kFeatureDims + audio::kTempoIndex];
      const audio::TempoClock::Span span = warp_.clock.Push(audio::TempoClock::TempoFromFeature(tempo));
      if (span.frame >= warp_.next_output) warp_.starts.push_back(span.begin);
      for (int64_t j = span.first_warped; j < span.end_warped; ++j) {
        warp_.source.push_back(span.frame);
        warp_.rate.push_back(span.rate);
      }
    }
  }
  frames_total_ += n;
  if (warped()) EmitWarpedFrames();
}

int Session::StepsReady() const {
  const int fps = model_->config().frames_per_step;
  if (warped()) {
    int64_t usable = warp_.clock.warped_frames();
    if (warp_.warped_limit >= 0) usable = std::min(usable, warp_.warped_limit);
    const int64_t total_steps = usable / fps - model_->config().music_lookahead_steps;
    return static_cast<int>(std::max<int64_t>(0, total_steps - cond_.step));
  }
  const int64_t usable = frames_limit_ >= 0 ? std::min(frames_total_, frames_limit_) : frames_total_;
  const int64_t total_steps = usable / fps - model_->config().music_lookahead_steps;
  return static_cast<int>(std::max<int64_t>(0, total_steps - cond_.step));
}

void Session::StepInputs(const float** music, const float** pre) {
  const int fps = model_->config().frames_per_step;
  if (warped()) {
    // Gather the token's warped frames from their source frames (docs/model.md section 8).
    const int64_t first_warped = (cond_.step + model_->config().music_lookahead_steps) * fps;
    music_token_.resize(static_cast<size_t>(fps) * kFeatureDims);
    int64_t src = 0;
    for (int f = 0; f < fps; ++f) {
      const int64_t w = first_warped + f - warp_.first_source;
      src = warp_.source[w] - first_pending_frame_;
      float* row = music_token_.data() + static_cast<size_t>(f) * kFeatureDims;
      std::copy_n(pending_features_.data() + src * kFeatureDims, kFeatureDims, row);
      if (model_->fold_tempo()) audio::FoldTempoFeatures(warp_.rate[w], row);
      if (bar_frames_ > 0.0) audio::BarClockPhase(first_warped + f, bar_frames_, row);
    }
    *music = music_token_.data();
    *pre = pending_pre_.data() + src * kPreDims;
    return;
  }
  const int64_t first = (cond_.step + model_->config().music_lookahead_steps) * fps - first_pending_frame_;
  *music = pending_features_.data() + first * kFeatureDims;
  *pre = pending_pre_.data() + (first + fps - 1) * kPreDims;
}

void Session::SampleCodes(const LaneLogits& cond, const LaneLogits& uncond, const LaneLogits& music_cond,
                          const LaneLogits& music_uncond) {
  const SeqConfig& c = model_->config();
  const int k = c.codebook_size;
  heading_history_.push_back(pose_.yaw);  // the heading after every frame of the previous steps
  if (heading_history_.size() > kMaxCodeHistory + 1) heading_history_.pop_front();
  absl::Span<const float> lu(cond.u, k), ll(cond.l, k);
  const bool combined = uncond.u != nullptr || music_cond.u != nullptr;
  if (combined) {
    std::copy(cond.u, cond.u + k, guided_u_.begin());
    std::copy(cond.l, cond.l + k, guided_l_.begin());
    if (uncond.u != nullptr) {
      ApplyGuidance(absl::MakeConstSpan(uncond.u, k), guidance(), absl::MakeSpan(guided_u_));
      ApplyGuidance(absl::MakeConstSpan(uncond.l, k), guidance(), absl::MakeSpan(guided_l_));
    }
    if (music_cond.u != nullptr) {
      // l_nm, style-guided like l, then l_nm + m (l - l_nm).
      std::copy(music_cond.u, music_cond.u + k, music_u_.begin());
      std::copy(music_cond.l, music_cond.l + k, music_l_.begin());
      if (music_uncond.u != nullptr) {
        ApplyGuidance(absl::MakeConstSpan(music_uncond.u, k), guidance(), absl::MakeSpan(music_u_));
        ApplyGuidance(absl::MakeConstSpan(music_uncond.l, k), guidance(), absl::MakeSpan(music_l_));
      }
      ApplyGuidance(music_u_, music_guidance(), absl::MakeSpan(guided_u_));
      ApplyGuidance(music_l_, music_guidance(), absl::MakeSpan(guided_l_));
    }
    lu = guided_u_;
    ll = guided_l_;
  }
  // Each stream locks once its lag's codes exist (the lower body's lag may be longer than the upper's).
  const bool lock_u = period_lock() > 0.0f && period_steps_ > 0.0 && code_history_.size() >= lock_lag(0);
  const bool lock_l = period_lock() > 0.0f && period_steps_ > 0.0 && code_history_.size() >= lock_lag(1);
  if (lock_u || lock_l) {
    if (!combined) {
      std::copy(cond.u, cond.u + k, guided_u_.begin());
      std::copy(cond.l, cond.l + k, guided_l_.begin());
    }
    if (lock_u && PeriodMoves(0)) ApplyPeriodLock(0, absl::MakeSpan(guided_u_));
    if (lock_l && PeriodMoves(1) && !PeriodTurned()) ApplyPeriodLock(1, absl::MakeSpan(guided_l_));
    lu = guided_u_;
    ll = guided_l_;
  }
  if (CrouchGuardActive()) {
    if (ll.data() != guided_l_.data()) {
      std::copy(ll.begin(), ll.end(), guided_l_.begin());
      ll = guided_l_;
    }
    for (int i : model_->crouched_lower_codes()) guided_l_[i] = -std::numeric_limits<float>::infinity();
  }
  SamplingOptions effective = sampling_;  // SampleCode reads temperature, top-k and top-p
  effective.top_p = top_p();
  upper_code_ = SampleCode(lu, effective, generator_, sampler_);
  lower_code_ = SampleCode(ll, effective, generator_, sampler_);
  code_history_.emplace_back(upper_code_, lower_code_);
  if (code_history_.size() > kMaxCodeHistory) code_history_.pop_front();
}

bool PeriodMoved(const std::deque<std::pair<int, int>>& history, int stream, size_t lag, int codebook_size,
                 std::vector<uint8_t>* seen) {
  std::vector<uint8_t> local;
  if (seen == nullptr) seen = &local;
  seen->assign(codebook_size, 0);
  size_t distinct = 0;
  for (size_t back = 1; back <= lag && back <= history.size(); ++back) {
    const auto& c = history[history.size() - back];
    const int code = stream == 0 ? c.first : c.second;
    if (code < 0 || code >= codebook_size) continue;
    distinct += (*seen)[code] == 0;
    (*seen)[code] = 1;
  }
  return distinct >= 2 && 2 * distinct >= lag;
}

bool Session::PeriodMoves(int stream) {
  // Stillness is periodic too: a lock that repeated a held pose would hold it for the rest of the song
  // (measured: the cha-cha and rumba froze, 1-2 distinct codes per 2 s against 12 unlocked). So the lock
  // repeats only a period in which this stream moved.
  return PeriodMoved(code_history_, stream, lock_lag(stream), model_->config().codebook_size, &lock_seen_);
}

bool PeriodTurned(const std::deque<double>& headings, size_t lag, double max_turn) {
  if (lag == 0 || headings.size() < lag + 1) return false;
  return std::abs(headings.back() - headings[headings.size() - 1 - lag]) > max_turn;
}

bool Session::CrouchGuardActive() const { return sampling_.crouch_guard && crouch_guard_on_; }

void UpdateCrouchGuard(bool crouched, double* load, bool* active) {
  static const double kKeep = std::exp(-1.0 / kCrouchDecayFrames);
  *load = *load * kKeep + (crouched ? 1.0 : 0.0);
  if (*load > kCrouchGuardOn) *active = true;
  if (*load < kCrouchGuardOff) *active = false;
}

bool Session::PeriodTurned() const { return engine::PeriodTurned(heading_history_, lock_lag(1)); }

void Session::ApplyPeriodLock(int stream, absl::Span<float> logits) {
  // The target is the code n = m round(L) steps back (L = period_steps_, rarely an integer; m the stream's
  // period_lock_periods): a constant lag,
  // so a locked dance repeats its codes in order. (Blending the codes at floor(L) and ceil(L) made a locked
  // dance stutter, repeating or skipping a code whenever it switched lag: FID_k 72 against 37 at weight 8.)
  // The bias of code i is lock x exp((s_i - 1) x sharpness), s_i its cosine similarity to the target and
  // sharpness the model's period_lock_sharpness (20 unless its metadata says otherwise).
  const RowMatrix& unit = model_->unit_codebook(stream);
  const float lock = period_lock();
  const float sharpness = model_->period_lock_sharpness();
  const auto& [up, low] = code_history_[code_history_.size() - lock_lag(stream)];
  lock_sim_.resize(unit.rows());
  lock_sim_.noalias() = unit * unit.row(stream == 0 ? up : low).transpose();
  for (size_t i = 0; i < logits.size(); ++i) {
    logits[i] += lock * std::exp((lock_sim_[static_cast<Eigen::Index>(i)] - 1.0f) * sharpness);
  }
}

void Session::EmitFrames(const Eigen::Ref<const Eigen::MatrixXf>& up, const Eigen::Ref<const Eigen::MatrixXf>& low) {
  const SeqConfig& c = model_->config();
  // cond_.step was advanced by the model: the step just taken is cond_.step - 1, emitting period cond_.step.
  const int64_t first_frame = cond_.step * c.frames_per_step;
  for (int f = 0; f < c.frames_per_step; ++f) {
    UpdateCrouchGuard(low(kLowerHeightIndex, f) < model_->crouch_height(), &crouch_load_, &crouch_guard_on_);
  }
  if (warped()) {
    for (int f = 0; f < c.frames_per_step; ++f) {
      std::array<Eigen::Vector3f, 24>& p = warp_.poses.emplace_back();
      reconstructor_.Reconstruct(up.col(f).data(), low.col(f).data(), pose_, &p, nullptr);
      warp_.pose_codes.emplace_back(upper_code_, lower_code_);
    }
    EmitWarpedFrames();
    // Forget warped sources and feature frames no step will read again.
    const int64_t next_warped = (cond_.step + c.music_lookahead_steps) * c.frames_per_step;
    while (warp_.first_source < next_warped && !warp_.source.empty()) {
      warp_.source.pop_front();
      warp_.rate.pop_front();
      ++warp_.first_source;
    }
    const int64_t needed_from = warp_.source.empty() ? frames_total_ : warp_.source.front();
    const int64_t drop = needed_from - first_pending_frame_;
    if (drop >= 256) {
      pending_features_.erase(pending_features_.begin(), pending_features_.begin() + drop * kFeatureDims);
      pending_pre_.erase(pending_pre_.begin(), pending_pre_.begin() + drop * kPreDims);
      first_pending_frame_ += drop;
    }
    return;
  }
  for (int f = 0; f < c.frames_per_step; ++f) {
    PoseFrame& frame = output_.emplace_back();
    frame.index = first_frame + f;
    frame.time_s = static_cast<double>(frame.index) / audio::kFrameRate;
    frame.upper_code = upper_code_;
    frame.lower_code = lower_code_;
    reconstructor_.Reconstruct(up.col(f).data(), low.col(f).data(), pose_, &frame.positions, nullptr);
    FinishFrame(frame);
  }
  // Forget feature frames no step will read again (amortised: only when many have accumulated).
  const int64_t needed_from = (cond_.step + c.music_lookahead_steps) * c.frames_per_step;
  const int64_t drop = needed_from - first_pending_frame_;
  if (drop >= 256) {
    pending_features_.erase(pending_features_.begin(), pending_features_.begin() + drop * kFeatureDims);
    pending_pre_.erase(pending_pre_.begin(), pending_pre_.begin() + drop * kPreDims);
    first_pending_frame_ += drop;
  }
}

void Session::EmitWarpedFrames() {
  const int64_t decoded_end = warp_.first_pose + static_cast<int64_t>(warp_.poses.size());
  while (!warp_.starts.empty() && (warp_.output_limit < 0 || warp_.next_output < warp_.output_limit)) {
    // Warped position of real frame m, held at the first decoded pose before the dance starts. The pair
    // (a, a + 1) with a < w <= a + 1 keeps frame m causal: pose a + 1 comes from a step that read warped
    // music up to a < W_m, whose source frames are all < m.
    const double w = std::max(warp_.starts.front(), static_cast<double>(warp_.first_pose) + 1.0);
    const int64_t a = static_cast<int64_t>(std::ceil(w)) - 1;
    if (a + 1 >= decoded_end) break;  // its poses are not decoded yet
    const float frac = static_cast<float>(w - static_cast<double>(a));
    const auto& pa = warp_.poses[a - warp_.first_pose];
    const auto& pb = warp_.poses[a + 1 - warp_.first_pose];
    PoseFrame& frame = output_.emplace_back();
    frame.index = warp_.next_output;
    frame.time_s = static_cast<double>(frame.index) / audio::kFrameRate;
    for (int j = 0; j < 24; ++j) frame.positions[j] = pa[j] + frac * (pb[j] - pa[j]);
    reconstructor_.ProjectBoneLengths(frame.positions);
    FinishFrame(frame);
    std::tie(frame.upper_code, frame.lower_code) = warp_.pose_codes[a - warp_.first_pose];
    warp_.starts.pop_front();
    ++warp_.next_output;
    // Poses before a are never needed again (W only grows).
    while (warp_.first_pose < a) {
      warp_.poses.pop_front();
      warp_.pose_codes.pop_front();
      ++warp_.first_pose;
    }
  }
}

void Session::FinishFrame(PoseFrame& frame) {
  if (sampling_.foot_lock) {
    foot_lock_.Apply(foot_lock_state_, &frame.positions);
  } else {
    // Turned off mid-stream (Session::SetSampling; the server never does), a held foot returns to its
    // decoded place at once; turned back on, the lock starts from the feet where they are.
    foot_lock_state_ = FootLockState();
  }
  reconstructor_.JointRotations(frame.positions, &frame.rotations);
}

absl::Status Session::Step() {
  Session* self = this;
  return StepBatch(absl::MakeConstSpan(&self, 1));
}

void Session::PopFrames(std::vector<PoseFrame>* out) {
  out->insert(out->end(), output_.begin(), output_.end());
  output_.clear();
}

absl::StatusOr<SessionSnapshot> Session::Snapshot() const {
  SessionSnapshot s;
  s.input_sample_rate = options_.input_sample_rate;
  s.input_channels = options_.input_channels;
  s.style = style_;
  s.sampling = sampling_;
  s.generator = generator_;
  s.front_end = front_end_->Snapshot();
  s.pending_features = pending_features_;
  s.pending_pre = pending_pre_;
  s.first_pending_frame = first_pending_frame_;
  s.frames_total = frames_total_;
  s.frames_limit = frames_limit_;
  s.ended = ended_;
  s.cond = cond_;
  s.uncond = uncond_;
  s.music_cond = music_cond_;
  s.music_uncond = music_uncond_;
  s.uncond_live = uncond_live_;
  s.music_cond_live = music_cond_live_;
  s.music_uncond_live = music_uncond_live_;
  s.upper_code = upper_code_;
  s.lower_code = lower_code_;
  s.upper_decoder = upper_state_;
  s.lower_decoder = lower_state_;
  s.pose = pose_;
  s.foot_lock = foot_lock_state_;
  s.warp = warp_;
  s.bar_frames = bar_frames_;
  s.period_steps = period_steps_;
  s.code_history = code_history_;
  s.heading_history = heading_history_;
  s.crouch_load = crouch_load_;
  s.crouch_guard_on = crouch_guard_on_;
  s.output = output_;
  return s;
}

absl::Status Session::Restore(const SessionSnapshot& s) {
  if (s.input_sample_rate != options_.input_sample_rate || s.input_channels != options_.input_channels) {
    return absl::InvalidArgumentError("session restore: snapshot has a different input format");
  }
  const SequenceState fresh = model_->sequence().NewState();
  if (s.cond.keys.size() != fresh.keys.size() || s.cond.conv.size() != fresh.conv.size() ||
      s.cond.style_bias.rows() != fresh.style_bias.rows() || s.cond.style_bias.cols() != fresh.style_bias.cols() ||
      (!s.cond.keys.empty() && s.cond.keys[0].size() != fresh.keys[0].size()) ||
      s.upper_decoder.history.size() != upper_state_.history.size() ||
      s.lower_decoder.history.size() != lower_state_.history.size()) {
    return absl::InvalidArgumentError("session restore: snapshot is from a different model");
  }
  for (const SequenceState* lane : {&s.uncond, &s.music_cond, &s.music_uncond}) {
    if (!lane->keys.empty() && (lane->keys.size() != fresh.keys.size() || lane->conv.size() != fresh.conv.size() ||
                                lane->keys[0].size() != fresh.keys[0].size())) {
      return absl::InvalidArgumentError("session restore: snapshot is from a different model");
    }
  }
  const int k = model_->config().codebook_size;
  for (const auto& [up, low] : s.code_history) {
    if (up < 0 || up >= k || low < 0 || low >= k || s.code_history.size() > kMaxCodeHistory) {
      return absl::InvalidArgumentError("session restore: snapshot has codes outside this model's codebook");
    }
  }
  if (s.heading_history.size() > kMaxCodeHistory + 1) {
    return absl::InvalidArgumentError("session restore: snapshot's heading history is too long");
  }
  DANCE_RETURN_IF_ERROR(ValidateSamplingOptions(s.sampling));
  DANCE_RETURN_IF_ERROR(front_end_->Restore(s.front_end));
  style_ = s.style;
  style_is_none_ = StyleIsNone(style_);
  sampling_ = s.sampling;
  generator_ = s.generator;
  pending_features_ = s.pending_features;
  pending_pre_ = s.pending_pre;
  first_pending_frame_ = s.first_pending_frame;
  frames_total_ = s.frames_total;
  frames_limit_ = s.frames_limit;
  ended_ = s.ended;
  cond_ = s.cond;
  uncond_ = s.uncond;
  music_cond_ = s.music_cond;
  music_uncond_ = s.music_uncond;
  uncond_live_ = s.uncond_live;
  music_cond_live_ = s.music_cond_live && !music_cond_.keys.empty();
  music_uncond_live_ = s.music_uncond_live && !music_uncond_.keys.empty();
  upper_code_ = s.upper_code;
  lower_code_ = s.lower_code;
  upper_state_ = s.upper_decoder;
  lower_state_ = s.lower_decoder;
  pose_ = s.pose;
  foot_lock_state_ = s.foot_lock;
  warp_ = s.warp;
  style_reference_bpm_ = warp_.clock.options().reference_bpm;
  bar_frames_ = s.bar_frames;
  period_steps_ = s.period_steps;
  // From the snapshot's style and this model (not copied: a snapshot of another model with the same shapes
  // would otherwise bring that model's weight).
  style_period_lock_ = model_->StylePeriodLock(TopStyleRow(style_));
  code_history_ = s.code_history;
  heading_history_ = s.heading_history;
  crouch_load_ = s.crouch_load;
  crouch_guard_on_ = s.crouch_guard_on;
  output_ = s.output;
  return absl::OkStatus();
}

void Session::Reset() {
  front_end_->Reset();
  popped_.Clear();
  pending_features_.clear();
  pending_pre_.clear();
  first_pending_frame_ = 0;
  frames_total_ = 0;
  frames_limit_ = -1;
  ended_ = false;
  generator_.seed(options_.seed);
  sampling_ = options_.sampling;
  const SequenceModel& seq = model_->sequence();
  cond_ = seq.NewState();
  uncond_ = seq.NewState();
  music_cond_ = SequenceState();
  music_uncond_ = SequenceState();
  uncond_live_ = music_cond_live_ = music_uncond_live_ = false;
  style_is_none_ = true;  // both fresh lanes have style "none"
  ApplyStyle(options_.style).IgnoreError();  // validated by Create
  upper_code_ = lower_code_ = model_->config().codebook_size;
  code_history_.clear();
  heading_history_.clear();
  crouch_load_ = 0.0;
  crouch_guard_on_ = false;
  upper_state_.Clear();
  lower_state_.Clear();
  pose_ = PoseState();
  foot_lock_state_ = FootLockState();
  warp_ = NewWarpState();
  output_.clear();
}

int64_t Session::StateBytes() const {
  int64_t n = static_cast<int64_t>(sizeof(*this)) + cond_.Bytes() + upper_state_.Bytes() + lower_state_.Bytes();
  if (uses_guidance()) n += uncond_.Bytes();
  if (!music_cond_.keys.empty()) n += music_cond_.Bytes();
  if (!music_uncond_.keys.empty()) n += music_uncond_.Bytes();
  n += static_cast<int64_t>(sizeof(audio::AudioFrontEnd) + sizeof(audio::FeatureExtractorState));
  n += static_cast<int64_t>((pending_features_.capacity() + pending_pre_.capacity()) * sizeof(float));
  n += static_cast<int64_t>(code_history_.size() * sizeof(code_history_[0]) +
                            heading_history_.size() * sizeof(double) + lock_sim_.size() * sizeof(float) +
                            lock_seen_.capacity());
  n += static_cast<int64_t>(warp_.source.size() * (sizeof(int64_t) + sizeof(double)) +
                            warp_.starts.size() * sizeof(double) +
                            warp_.poses.size() * (sizeof(warp_.poses[0]) + sizeof(warp_.pose_codes[0])));
  return n;
}

absl::Status StepBatch(absl::Span<Session* const> sessions) {
  thread_local Workspace workspace;
  thread_local std::vector<LaneInput> lanes;
  thread_local std::vector<Session*> sorted;
  thread_local std::vector<int> first_lane;
  thread_local std::vector<Session*> group;
  thread_local std::vector<int> upper_codes, lower_codes;
  thread_local std::vector<VqDecoderState*> upper_states, lower_states;
  thread_local VqDecoderScratch upper_scratch, lower_scratch;
  sorted.assign(sessions.begin(), sessions.end());
  std::sort(sorted.begin(), sorted.end());
  if (std::adjacent_find(sorted.begin(), sorted.end()) != sorted.end()) {
    return absl::InvalidArgumentError("StepBatch: a session appears twice");
  }
  for (Session* s : sessions) {
    if (s == nullptr) return absl::InvalidArgumentError("StepBatch: null session");
    if (s->StepsReady() <= 0) {
      return absl::FailedPreconditionError(
          absl::StrCat("StepBatch: a session has no step ready (its audio for step ", s->steps_done(),
                       " has not arrived)"));
    }
  }
  // One pass per distinct model (normally exactly one).
  size_t done = 0;
  std::vector<bool> handled;  // only when several models share a batch (rare)
  while (done < sessions.size()) {
    const Model* model = nullptr;
    lanes.clear();
    first_lane.clear();
    for (size_t i = 0; i < sessions.size(); ++i) {
      Session* s = sessions[i];
      if (!handled.empty() && handled[i]) continue;
      if (model == nullptr) model = s->model_.get();
      if (s->model_.get() != model) {
        if (handled.empty()) handled.assign(sessions.size(), false);
        first_lane.push_back(-1);
        continue;
      }
      s->PrepareLanes();
      LaneInput in;
      s->StepInputs(&in.music, &in.pre);
      in.upper_code = s->upper_code_;
      in.lower_code = s->lower_code_;
      in.state = &s->cond_;
      first_lane.push_back(static_cast<int>(lanes.size()));
      lanes.push_back(in);
      if (s->uncond_live_) {
        in.state = &s->uncond_;
        lanes.push_back(in);
      }
      if (s->music_cond_live_) {
        in.music = s->MeanMusicToken(in.music);
        in.state = &s->music_cond_;
        lanes.push_back(in);
        if (s->music_uncond_live_) {
          in.state = &s->music_uncond_;
          lanes.push_back(in);
        }
      }
    }
    model->sequence().Step(lanes, workspace);
    size_t slot = 0;
    for (size_t i = 0; i < sessions.size(); ++i) {
      if (!handled.empty() && handled[i]) continue;
      const int lane = first_lane[slot++];
      if (lane < 0) continue;
      Session* s = sessions[i];
      // The session's lanes in PrepareLanes' order: cond, [uncond], [music cond, [music uncond]].
      int next = lane;
      auto take = [&](bool live) {
        Session::LaneLogits g;
        if (!live) return g;
        g.u = workspace.logits_u.col(next).data();
        g.l = workspace.logits_l.col(next).data();
        ++next;
        return g;
      };
      const Session::LaneLogits cond = take(true);
      const Session::LaneLogits uncond = take(s->uncond_live_);
      const Session::LaneLogits music_cond = take(s->music_cond_live_);
      const Session::LaneLogits music_uncond = take(s->music_uncond_live_);
      s->SampleCodes(cond, uncond, music_cond, music_uncond);
      group.push_back(s);
    }
    // Both VQ decoders over the whole group (one GEMM per conv), then per-session reconstruction.
    upper_codes.clear();
    lower_codes.clear();
    upper_states.clear();
    lower_states.clear();
    for (Session* s : group) {
      upper_codes.push_back(s->upper_code_);
      lower_codes.push_back(s->lower_code_);
      upper_states.push_back(&s->upper_state_);
      lower_states.push_back(&s->lower_state_);
    }
    const auto up = model->upper_decoder().DecodeBatch(upper_codes, upper_states, upper_scratch);
    const auto low = model->lower_decoder().DecodeBatch(lower_codes, lower_states, lower_scratch);
    const int fpc = model->config().frames_per_step;
    for (size_t g = 0; g < group.size(); ++g) {
      group[g]->EmitFrames(up.middleCols(g * fpc, fpc), low.middleCols(g * fpc, fpc));
    }
    for (size_t i = 0; i < sessions.size(); ++i) {
      if (!handled.empty() && sessions[i]->model_.get() == model) handled[i] = true;
    }
    done += group.size();
    group.clear();
  }
  return absl::OkStatus();
}

}  // namespace dance::engine
