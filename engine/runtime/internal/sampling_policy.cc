#include "engine/runtime/internal/sampling_policy.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "engine/nn/status_macros.h"

namespace dance::engine {

static_assert(kMaxCodeHistory >= kMaxPeriodLockPeriods * 240);

SamplingPolicy::SamplingPolicy(const Model& model, uint64_t seed, const SamplingOptions& options)
    : model_(&model), sampler_(model.config().codebook_size) {
  state_.options = options;
  state_.generator.seed(seed);
  const int k = model.config().codebook_size;
  guided_u_.resize(k);
  guided_l_.resize(k);
  music_u_.resize(k);
  music_l_.resize(k);
}

void SamplingPolicy::SetStyle(const ResolvedStyle& style) {
  state_.style = style.mix;
  style_is_none_ = style.is_none;
  // The metre, dance period and period lock weight follow the style with the largest weight.
  style_period_lock_ = style.period_lock;
  if (model_->tempo_reference_bpm() > 0.0) state_.period_steps = style.period_steps;
}

absl::Status SamplingPolicy::SetSampling(const SamplingOptions& options) {
  DANCE_RETURN_IF_ERROR(ValidateSamplingOptions(options));
  state_.options = options;  // lanes switched on start at the next step (SequenceLanes::Prepare)
  return absl::OkStatus();
}

size_t SamplingPolicy::lock_lag(int stream) const {
  return static_cast<size_t>(model_->period_lock_periods(stream)) *
         static_cast<size_t>(std::max(1.0, std::round(state_.period_steps)));
}

std::pair<int, int> SamplingPolicy::Sample(const StepLogits& logits, double yaw, const StepControl* control) {
  SamplingState& s = state_;
  const int k = model_->config().codebook_size;
  const LaneLogits& cond = logits.cond;
  s.heading_history.push_back(yaw);  // the heading after every frame of the previous steps
  if (s.heading_history.size() > kMaxCodeHistory + 1) s.heading_history.pop_front();
  absl::Span<const float> lu(cond.u, k), ll(cond.l, k);
  const bool combined = logits.uncond.u != nullptr || logits.music_cond.u != nullptr;
  if (combined) {
    std::copy(cond.u, cond.u + k, guided_u_.begin());
    std::copy(cond.l, cond.l + k, guided_l_.begin());
    if (logits.uncond.u != nullptr) {
      ApplyGuidance(absl::MakeConstSpan(logits.uncond.u, k), guidance(), absl::MakeSpan(guided_u_));
      ApplyGuidance(absl::MakeConstSpan(logits.uncond.l, k), guidance(), absl::MakeSpan(guided_l_));
    }
    if (logits.music_cond.u != nullptr) {
      // l_nm, style-guided like l, then l_nm + m (l - l_nm).
      std::copy(logits.music_cond.u, logits.music_cond.u + k, music_u_.begin());
      std::copy(logits.music_cond.l, logits.music_cond.l + k, music_l_.begin());
      if (logits.music_uncond.u != nullptr) {
        ApplyGuidance(absl::MakeConstSpan(logits.music_uncond.u, k), guidance(), absl::MakeSpan(music_u_));
        ApplyGuidance(absl::MakeConstSpan(logits.music_uncond.l, k), guidance(), absl::MakeSpan(music_l_));
      }
      ApplyGuidance(music_u_, music_guidance(), absl::MakeSpan(guided_u_));
      ApplyGuidance(music_l_, music_guidance(), absl::MakeSpan(guided_l_));
    }
    lu = guided_u_;
    ll = guided_l_;
  }
  // Each stream locks once its lag's codes exist (the lower body's lag may be longer than the upper's).
  const bool lock_on = period_lock() > 0.0f && s.period_steps > 0.0;
  const bool lock_u = lock_on && s.code_history.size() >= lock_lag(0);
  const bool lock_l = lock_on && s.code_history.size() >= lock_lag(1);
  if (lock_u || lock_l) {
    if (!combined) {
      std::copy(cond.u, cond.u + k, guided_u_.begin());
      std::copy(cond.l, cond.l + k, guided_l_.begin());
    }
    // A stream the controls force or pull is not locked (the constraint is the stronger term).
    const bool free_u = control == nullptr || (control->forced[0] < 0 && control->pull[0] < 0);
    const bool free_l = control == nullptr || (control->forced[1] < 0 && control->pull[1] < 0);
    if (lock_u && free_u && PeriodMoves(0)) ApplyPeriodLock(0, absl::MakeSpan(guided_u_));
    if (lock_l && free_l && PeriodMoves(1) && !PeriodTurned(s.heading_history, lock_lag(1))) {
      ApplyPeriodLock(1, absl::MakeSpan(guided_l_));
    }
    lu = guided_u_;
    ll = guided_l_;
  }
  if (s.options.crouch_guard && s.crouch_guard_on) {
    if (ll.data() != guided_l_.data()) {
      std::copy(ll.begin(), ll.end(), guided_l_.begin());
      ll = guided_l_;
    }
    for (int i : model_->crouched_lower_codes()) guided_l_[i] = -std::numeric_limits<float>::infinity();
  }
  if (control != nullptr && (control->pull[0] >= 0 || control->pull[1] >= 0 || control->lower_bias != nullptr)) {
    for (int stream = 0; stream < 2; ++stream) {
      absl::Span<const float>& from = stream == 0 ? lu : ll;
      std::vector<float>& to = stream == 0 ? guided_u_ : guided_l_;
      const bool touch = control->pull[stream] >= 0 || (stream == 1 && control->lower_bias != nullptr);
      if (!touch || control->forced[stream] >= 0) continue;
      if (from.data() != to.data()) {
        std::copy(from.begin(), from.end(), to.begin());
        from = to;
      }
      if (control->pull[stream] >= 0) {
        AddCodePull(stream, control->pull[stream], control->pull_weight, absl::MakeSpan(to));
      }
      if (stream == 1 && control->lower_bias != nullptr) {
        for (int i = 0; i < k; ++i) to[i] += control->lower_bias[i];
      }
    }
  }
  SamplingOptions effective = s.options;  // SampleCode reads temperature, top-k and top-p
  effective.top_p = top_p();
  const int upper = control != nullptr && control->forced[0] >= 0 ? control->forced[0]
                                                                  : SampleCode(lu, effective, s.generator, sampler_);
  const int lower = control != nullptr && control->forced[1] >= 0 ? control->forced[1]
                                                                  : SampleCode(ll, effective, s.generator, sampler_);
  s.code_history.emplace_back(upper, lower);
  if (s.code_history.size() > kMaxCodeHistory) s.code_history.pop_front();
  return {upper, lower};
}

void SamplingPolicy::ObserveDecodedHeight(float pelvis_height) {
  UpdateCrouchGuard(pelvis_height < model_->crouch_height(), &state_.crouch_load, &state_.crouch_guard_on);
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

bool SamplingPolicy::PeriodMoves(int stream) {
  // Stillness is periodic too: a lock that repeated a held pose would hold it for the rest of the song
  // (measured: the cha-cha and rumba froze, 1-2 distinct codes per 2 s against 12 unlocked). So the lock
  // repeats only a period in which this stream moved.
  return PeriodMoved(state_.code_history, stream, lock_lag(stream), model_->config().codebook_size, &lock_seen_);
}

bool PeriodTurned(const std::deque<double>& headings, size_t lag, double max_turn) {
  if (lag == 0 || headings.size() < lag + 1) return false;
  return std::abs(headings.back() - headings[headings.size() - 1 - lag]) > max_turn;
}

void UpdateCrouchGuard(bool crouched, double* load, bool* active) {
  static const double kKeep = std::exp(-1.0 / kCrouchDecayFrames);
  *load = *load * kKeep + (crouched ? 1.0 : 0.0);
  if (*load > kCrouchGuardOn) *active = true;
  if (*load < kCrouchGuardOff) *active = false;
}

void SamplingPolicy::ApplyPeriodLock(int stream, absl::Span<float> logits) {
  // The target is the code n = m round(L) steps back (L = period_steps, rarely an integer; m the stream's
  // period_lock_periods): a constant lag, so a locked dance repeats its codes in order. (Blending the codes
  // at floor(L) and ceil(L) made a locked dance stutter, repeating or skipping a code whenever it switched
  // lag: FID_k 72 against 37 at weight 8.) The bias of code i is lock x exp((s_i - 1) x sharpness), s_i its
  // cosine similarity to the target and sharpness the model's period_lock_sharpness (20 unless its metadata
  // says otherwise).
  const RowMatrix& unit = model_->unit_codebook(stream);
  const float lock = period_lock();
  const float sharpness = model_->period_lock_sharpness();
  const auto& [up, low] = state_.code_history[state_.code_history.size() - lock_lag(stream)];
  lock_sim_.resize(unit.rows());
  lock_sim_.noalias() = unit * unit.row(stream == 0 ? up : low).transpose();
  for (size_t i = 0; i < logits.size(); ++i) {
    logits[i] += lock * std::exp((lock_sim_[static_cast<Eigen::Index>(i)] - 1.0f) * sharpness);
  }
}

void SamplingPolicy::AddCodePull(int stream, int code, float weight, absl::Span<float> logits) {
  const RowMatrix& unit = model_->unit_codebook(stream);
  const float sharpness = model_->period_lock_sharpness();
  lock_sim_.resize(unit.rows());
  lock_sim_.noalias() = unit * unit.row(code).transpose();
  for (size_t i = 0; i < logits.size(); ++i) {
    logits[i] += weight * std::exp((lock_sim_[static_cast<Eigen::Index>(i)] - 1.0f) * sharpness);
  }
}

absl::Status SamplingPolicy::Validate(const SamplingState& s) const {
  const int k = model_->config().codebook_size;
  for (const auto& [up, low] : s.code_history) {
    if (up < 0 || up >= k || low < 0 || low >= k || s.code_history.size() > kMaxCodeHistory) {
      return absl::InvalidArgumentError("session restore: snapshot has codes outside this model's codebook");
    }
  }
  if (s.heading_history.size() > kMaxCodeHistory + 1) {
    return absl::InvalidArgumentError("session restore: snapshot's heading history is too long");
  }
  return ValidateSamplingOptions(s.options);
}

void SamplingPolicy::Restore(const SamplingState& s) {
  state_ = s;
  style_is_none_ = StyleIsNone(*model_, s.style);
  // From the snapshot's style and this model (not copied: a snapshot of another model with the same shapes
  // would otherwise bring that model's weight).
  style_period_lock_ = model_->StylePeriodLock(TopStyleRow(*model_, s.style));
}

void SamplingPolicy::Reset(uint64_t seed, const SamplingOptions& options, const ResolvedStyle& style) {
  state_ = SamplingState();
  state_.options = options;
  state_.generator.seed(seed);
  SetStyle(style);
}

int64_t SamplingPolicy::Bytes() const {
  return static_cast<int64_t>(state_.code_history.size() * sizeof(state_.code_history[0]) +
                              state_.heading_history.size() * sizeof(double) + lock_sim_.size() * sizeof(float) +
                              lock_seen_.capacity());
}

}  // namespace dance::engine
