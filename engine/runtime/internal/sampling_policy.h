// SamplingPolicy: how a session turns a step's lane logits into codes. It owns the sampling options, the
// style mix's name list and its period, the seeded generator, and the state of the locks that shape the
// choice: style guidance and music guidance (which lanes are needed and how they combine), the period lock
// (a bias toward the codes of one dance period ago, from the code and heading histories) and the crouch
// guard (a leaky count of crouched decoded frames). docs/model.md section 6.
//
// Usage (inside StepBatch):
//   lanes.Prepare(policy.uses_guidance(), policy.uses_music_guidance());
//   ... the model steps every lane ...
//   auto [u, l] = policy.Sample(lanes.Logits(ws, first), body.yaw());
//   for each decoded frame: policy.ObserveDecodedHeight(pelvis_height);
//
// State: every field that changes lives in SamplingState (snapshot = copy). Not thread-safe.
#ifndef DANCE_ENGINE_RUNTIME_INTERNAL_SAMPLING_POLICY_H_
#define DANCE_ENGINE_RUNTIME_INTERNAL_SAMPLING_POLICY_H_

#include <cstddef>
#include <cstdint>
#include <deque>
#include <random>
#include <utility>
#include <vector>

#include "Eigen/Core"
#include "absl/status/status.h"
#include "absl/types/span.h"
#include "engine/nn/sampling.h"
#include "engine/runtime/model.h"
#include "engine/runtime/internal/sequence_lanes.h"
#include "engine/runtime/style_mix.h"

namespace dance::engine {

// The longest code history the period lock reads: kMaxPeriodLockPeriods (4) periods of 16 beats at 30 BPM,
// 240 steps each.
inline constexpr size_t kMaxCodeHistory = 1024;

// What the session's controls (MotionControl) ask of one step; the default asks nothing.
struct StepControl {
  int forced[2] = {-1, -1};  // per stream (0 upper, 1 lower): the code this step must take, -1 = sample
  int pull[2] = {-1, -1};    // per stream: a code to pull the choice toward (the next known pose), -1 = none
  float pull_weight = 0.0f;  // the pull's logit bias at the target code (the period lock's kernel around it)
  const float* lower_bias = nullptr;  // (K) added to the lower logits (the trajectory), or null
};

struct SamplingState {
  SamplingOptions options;  // as set (negative fields = the model's defaults, resolved per step)
  StyleMix style;
  double period_steps = 0.0;  // the style's dance period in warped steps (0 = unknown: no lock)
  std::mt19937_64 generator;
  std::deque<std::pair<int, int>> code_history;  // (upper, lower) codes of the last steps, oldest first
  std::deque<double> heading_history;            // the body's yaw at the start of the last steps, oldest first
  double crouch_load = 0.0;      // leaky count of crouched decoded frames (UpdateCrouchGuard)
  bool crouch_guard_on = false;  // the load passed kCrouchGuardOn and has not decayed below kCrouchGuardOff
};

class SamplingPolicy {
 public:
  // `options` must be valid (ValidateSamplingOptions); the style comes with SetStyle.
  SamplingPolicy(const Model& model, uint64_t seed, const SamplingOptions& options);

  void SetStyle(const ResolvedStyle& style);
  // InvalidArgument naming the bad field; the options apply from the next step.
  absl::Status SetSampling(const SamplingOptions& options);

  // Samples this step's (upper, lower) codes from the lanes' logits (style guidance, music guidance, the
  // period lock and the crouch guard applied if on) and records them; `yaw` is the body's heading now.
  // `control` (may be null) forces, pulls or biases streams; a stream forced or pulled is not period-locked.
  std::pair<int, int> Sample(const StepLogits& logits, double yaw, const StepControl* control = nullptr);
  // One decoded frame's pelvis height, for the crouch guard.
  void ObserveDecodedHeight(float pelvis_height);

  const SamplingOptions& options() const { return state_.options; }
  const StyleMix& style() const { return state_.style; }
  // The weights in effect (the options', or the model's defaults where those are negative).
  float guidance() const {
    return state_.options.guidance < 0.0f ? model_->default_guidance() : state_.options.guidance;
  }
  float music_guidance() const {
    return state_.options.music_guidance < 0.0f ? model_->default_music_guidance() : state_.options.music_guidance;
  }
  float top_p() const { return state_.options.top_p < 0.0f ? model_->default_top_p() : state_.options.top_p; }
  float period_lock() const {
    return state_.options.period_lock < 0.0f ? style_period_lock_ : state_.options.period_lock;
  }
  // Guidance needs the unconditional lane only when the style is not "none" (with style "none" both lanes
  // are the same computation and lu + w (lc - lu) = lc).
  bool uses_guidance() const { return guidance() != 1.0f && !style_is_none_; }
  // Music guidance needs the lanes reading the music mean.
  bool uses_music_guidance() const { return music_guidance() != 1.0f; }
  const SamplingState& state() const { return state_; }

  // InvalidArgument for histories out of range or invalid options.
  absl::Status Validate(const SamplingState& state) const;
  // `state` must have passed Validate. The style's default lock weight is this model's, not copied.
  void Restore(const SamplingState& state);
  void Reset(uint64_t seed, const SamplingOptions& options, const ResolvedStyle& style);
  int64_t Bytes() const;

 private:
  // Adds the period lock's bias toward the code lock_lag(stream) steps ago to `logits` of `stream` (0 upper).
  void ApplyPeriodLock(int stream, absl::Span<float> logits);
  // Adds `weight` x the period lock's kernel around `code` of `stream` to `logits`.
  void AddCodePull(int stream, int code, float weight, absl::Span<float> logits);
  // Whether `stream` moved over its last lock_lag(stream) steps (at least half of them distinct codes).
  bool PeriodMoves(int stream);
  // The period lock's lag of `stream` in whole steps: the model's period_lock_periods(stream) times one
  // period in whole steps (>= 1), so a lower body locked two periods back stays in phase with an upper body
  // locked one period back (two periods of 7.5 steps are 2 x 8 = 16 steps, not 15).
  size_t lock_lag(int stream) const;

  const Model* model_;
  SamplingState state_;
  bool style_is_none_ = true;       // every weighted entry of the style is "none"
  float style_period_lock_ = 0.0f;  // the top style's default period lock weight (Model::StylePeriodLock)
  SamplerScratch sampler_;
  std::vector<float> guided_u_, guided_l_;  // (K) scratch
  std::vector<float> music_u_, music_l_;    // (K) scratch of music guidance
  Eigen::VectorXf lock_sim_;                // (K) scratch of the period lock
  std::vector<uint8_t> lock_seen_;          // (K) scratch of PeriodMoves
};

// Whether `stream` (0 upper, 1 lower) moved over the last `lag` entries of a code history (oldest first):
// at least half of them, and at least 2, distinct codes. The period lock applies to a stream only then.
// `seen` is optional scratch (codebook_size entries).
bool PeriodMoved(const std::deque<std::pair<int, int>>& history, int stream, size_t lag, int codebook_size,
                 std::vector<uint8_t>* seen = nullptr);

// The lower body's period lock is released for a period that turned the body by more than this (radians):
// repeating such a period spins the dancer without end (measured on the default model: 4-6 rad/s held for
// minutes, against real dancers' ~1 rad/s; docs/model.md section 6). Half a turn is about the 80th
// percentile of the real dancers' turn per 2 s (about one waltz bar).
inline constexpr double kPeriodLockMaxTurn = 3.14159265358979;

// Whether the heading changed by more than `max_turn` over the last `lag` steps of `headings` (the heading
// at the start of each step, oldest first; needs lag + 1 entries, false with fewer).
bool PeriodTurned(const std::deque<double>& headings, size_t lag, double max_turn = kPeriodLockMaxTurn);

// The crouch guard (SamplingOptions::crouch_guard): a decoded frame is crouched when its pelvis is below
// Model::crouch_height() (kCrouchHeightFraction of the standing height). The session keeps a leaky count of
// crouched decoded frames, load <- load exp(-1 / kCrouchDecayFrames) + crouched (30 s memory). Over the 38
// real Tang dances its maximum is 83 frames (a rumba dip of 2.9 s). When it passes kCrouchGuardOn (120:
// four seconds of crouching in one go, or repeated dips), the lower body's codes whose held pose is
// crouched (Model::crouched_lower_codes) are excluded from sampling until the load has decayed below
// kCrouchGuardOff (60; about 20 s of standing). Without it the default model can sink into a crouch with one
// leg lifted and stay there for minutes, and a guard that let go as soon as the pelvis rose saw it sink
// back at once (its own autoregressive drift; docs/research-log.md).
inline constexpr double kCrouchDecayFrames = 900.0;
inline constexpr double kCrouchGuardOn = 120.0;
inline constexpr double kCrouchGuardOff = 60.0;

// One decoded frame's update of the crouch guard's state (load and whether the guard is on).
void UpdateCrouchGuard(bool crouched, double* load, bool* active);

}  // namespace dance::engine

#endif  // DANCE_ENGINE_RUNTIME_INTERNAL_SAMPLING_POLICY_H_
