// Session: one performer's stream through the whole engine. It owns every piece of per-stream state
// (resampler, feature extractor + incremental PRE, the sequence model's KV caches and Mamba states, the
// sampler's generator, both VQ decoders' conv histories and the root integrator) behind one interface:
// push audio, step, pop pose frames; reset, snapshot and restore; change style or sampling mid-stream.
//
// Usage:
//   absl::StatusOr<std::shared_ptr<const Model>> model = LoadModel("models/default.dncw");
//   SessionOptions opt;  opt.input_sample_rate = 44100;  opt.input_channels = 2;  opt.seed = 7;
//   absl::StatusOr<std::unique_ptr<Session>> s = Session::Create(*model, opt);
//   (*s)->PushAudio(chunk);                       // any chunk size; interleaved float PCM in [-1, 1]
//   while ((*s)->StepsReady() > 0) (*s)->Step();  // or StepBatch over many sessions
//   std::vector<PoseFrame> frames;  (*s)->PopFrames(&frames);
//   ...  (*s)->EndOfAudio();  drain steps and frames the same way.
//
// Determinism: the same audio, options and seed give the same frames, however the audio is chunked and
// whether sessions step alone or batched. Snapshot() then Restore() continues exactly as if uninterrupted.
//
// Timeline: step t covers pose frames [4t, 4t + 4) and emits the frames of period t + 1 (docs/model.md
// section 2), so the first frame emitted has index 4 and time_s = 4/30 s. A step is ready when the audio of
// its music token (period t + music_lookahead_steps) has fully arrived; after EndOfAudio the last partial
// period is padded with silence so the dance covers the whole song.
// Tempo-normalised models (Model::tempo_reference_bpm() > 0; docs/model.md section 8): the steps run on
// the warped timeline of audio::TempoClock (its frames follow the music's running tempo), music tokens are
// gathered from each warped frame's source frame, and the decoded warped poses are resampled back onto
// the real 30 fps timeline: real frame m shows the warped pose at W_m (linear interpolation, then bone
// projection and rotations). Frame m is emitted as soon as real frames < m have arrived and its warped
// poses are decoded, so indices and times keep the meaning above (first index 4, contiguous).
//
// Errors: Create/SetStyle/SetSampling return InvalidArgument for bad settings (rate outside
// [8000, 96000], channels outside [1, 8], unknown style, negative temperature, ...); PushAudio refuses
// a chunk whose length is not a multiple of the channel count, and audio after EndOfAudio
// (FailedPrecondition); Step without a ready step is FailedPrecondition.
//
// Thread safety: a Session is not thread-safe (one owner at a time); different sessions may be used from
// different threads, sharing one Model. StepBatch needs all its sessions to be owned by the caller.
#ifndef DANCE_ENGINE_RUNTIME_SESSION_H_
#define DANCE_ENGINE_RUNTIME_SESSION_H_

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <deque>
#include <memory>
#include <random>
#include <string>
#include <utility>
#include <vector>

#include "Eigen/Core"
#include "Eigen/Geometry"
#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/types/span.h"
#include "engine/audio/audio_front_end.h"
#include "engine/audio/tempo_clock.h"
#include "engine/model/sequence_state.h"
#include "engine/nn/sampling.h"
#include "engine/runtime/model.h"
#include "engine/vq/foot_lock.h"
#include "engine/vq/pose_reconstructor.h"
#include "engine/vq/vq_decoder.h"

namespace dance::engine {

struct SessionOptions {
  int input_sample_rate = 24000;  // Hz, 8000..96000
  int input_channels = 1;         // 1..8, interleaved; downmixed to mono by averaging
  std::vector<std::pair<std::string, float>> style;  // empty = "none"; weights >= 0, normalised to sum 1
  uint64_t seed = 0;
  SamplingOptions sampling;
};

struct PoseFrame {
  int64_t index = 0;     // pose frame index since stream start (30 fps)
  double time_s = 0.0;   // audio time of this frame's start, seconds on the input timeline (index / 30)
  std::array<Eigen::Vector3f, 24> positions;     // metres, Y up, SMPL order, bone lengths canonical
  std::array<Eigen::Quaternionf, 24> rotations;  // local joint rotations (relative to the parent's frame)
  int upper_code = 0;
  int lower_code = 0;
};

// The tempo-normalised time base of a session (unused for fixed-rate models); copyable.
struct WarpState {
  audio::TempoClock clock;
  std::deque<int64_t> source;   // source real frame of warped frames [first_source, ...)
  std::deque<double> rate;      // clock rate r_n of each one's source frame (the tempo fold reads it)
  int64_t first_source = 0;
  std::deque<double> starts;    // W_m of real frames [next_output, clock.frames())
  int64_t next_output = 0;      // next real frame to emit
  std::deque<std::array<Eigen::Vector3f, 24>> poses;  // decoded warped frames [first_pose, ...), projected
  std::deque<std::pair<int, int>> pose_codes;         // their (upper, lower) codes
  int64_t first_pose = 0;
  int64_t warped_limit = -1;    // after EndOfAudio: warped frames the steps may read
  int64_t output_limit = -1;    // after EndOfAudio: real frames to emit (exclusive)
};

// Everything a Session remembers, as a copyable value (opaque to callers; valid only for a session of the
// same model and input format).
struct SessionSnapshot {
  int input_sample_rate = 0;
  int input_channels = 0;
  std::vector<std::pair<std::string, float>> style;
  SamplingOptions sampling;
  std::mt19937_64 generator;
  audio::AudioFrontEndSnapshot front_end;
  std::vector<float> pending_features;  // (frames, F) not consumed yet, from first_pending_frame
  std::vector<float> pending_pre;       // (frames, P)
  int64_t first_pending_frame = 0;
  int64_t frames_total = 0;
  int64_t frames_limit = -1;
  bool ended = false;
  SequenceState cond;
  SequenceState uncond;
  SequenceState music_cond;
  SequenceState music_uncond;
  bool uncond_live = false, music_cond_live = false, music_uncond_live = false;
  int upper_code = 0, lower_code = 0;
  VqDecoderState upper_decoder, lower_decoder;
  PoseState pose;
  FootLockState foot_lock;
  WarpState warp;
  double bar_frames = 0.0;
  double period_steps = 0.0;
  std::deque<std::pair<int, int>> code_history;
  std::deque<double> heading_history;
  double crouch_load = 0.0;
  bool crouch_guard_on = false;
  std::vector<PoseFrame> output;
};

class Session {
 public:
  static absl::StatusOr<std::unique_ptr<Session>> Create(std::shared_ptr<const Model> model,
                                                         const SessionOptions& options);
  ~Session();
  Session(const Session&) = delete;
  Session& operator=(const Session&) = delete;

  // Interleaved float samples at the input rate; any length that is a multiple of the channel count.
  // Non-finite samples are treated as 0.
  absl::Status PushAudio(absl::Span<const float> interleaved);
  // The same for 16-bit PCM (scaled by 1/32768).
  absl::Status PushAudioInt16(absl::Span<const int16_t> interleaved);
  // No more audio: flushes the resampler and pads the last period with silence.
  void EndOfAudio();
  // Code steps whose audio has fully arrived and that have not been taken yet.
  int StepsReady() const;
  // Advances one step (== StepBatch of this session alone).
  absl::Status Step();
  // Appends the frames produced so far, in order, to `out` and forgets them.
  void PopFrames(std::vector<PoseFrame>* out);

  // Changes the style from the next step on; InvalidArgument for an unknown name or a bad weight.
  absl::Status SetStyle(const std::vector<std::pair<std::string, float>>& style);
  absl::Status SetSampling(const SamplingOptions& sampling);

  absl::StatusOr<SessionSnapshot> Snapshot() const;
  absl::Status Restore(const SessionSnapshot& snapshot);
  // Back to the state right after Create (same options, seed and style).
  void Reset();

  // Declared model latency in ms (music lookahead; the front end adds none).
  double LatencyMs() const { return model_->LatencyMs(); }
  // Steps taken so far.
  int64_t steps_done() const { return cond_.step; }
  // The music token (frames_per_step x kNumFeatures, frame-major) the last step of a tempo-normalised
  // model read (its bar phase is the bar clock's if the model has one); for tests. Empty before the first
  // step and for fixed-rate models.
  const std::vector<float>& last_warped_music_token() const { return music_token_; }
  // The period lock weight in effect (SamplingOptions::period_lock, or if negative the model's weight for
  // the top style, Model::StylePeriodLock).
  float period_lock() const { return sampling_.period_lock < 0.0f ? style_period_lock_ : sampling_.period_lock; }
  // The sampling options as set (negative fields = the model's defaults, resolved per step).
  const SamplingOptions& sampling() const { return sampling_; }
  // The style guidance weight in effect (SamplingOptions::guidance, or the model's default if negative).
  float guidance() const { return EffectiveGuidance(sampling_); }
  // The music guidance weight in effect (SamplingOptions::music_guidance, or the model's default if negative).
  float music_guidance() const {
    return sampling_.music_guidance < 0.0f ? model_->default_music_guidance() : sampling_.music_guidance;
  }
  // The nucleus cut in effect (SamplingOptions::top_p, or the model's default if negative).
  float top_p() const { return sampling_.top_p < 0.0f ? model_->default_top_p() : sampling_.top_p; }
  // The (upper, lower) codes of the last step (the BOS code K before the first).
  std::pair<int, int> last_codes() const { return {upper_code_, lower_code_}; }
  // Approximate bytes of per-session state (caches, states, buffers).
  int64_t StateBytes() const;
  const Model& model() const { return *model_; }

 private:
  friend absl::Status StepBatch(absl::Span<Session* const> sessions);
  Session(std::shared_ptr<const Model> model, const SessionOptions& options);

  absl::Status ApplyStyle(const std::vector<std::pair<std::string, float>>& style);
  // Moves the front end's finished frames into pending_.
  void CollectFrames();
  float EffectiveGuidance(const SamplingOptions& s) const {
    return s.guidance < 0.0f ? model_->default_guidance() : s.guidance;
  }
  // Guidance needs the unconditional lane only when the style is not "none" (with style "none" both lanes
  // are the same computation and lu + w (lc - lu) = lc).
  bool uses_guidance() const { return guidance() != 1.0f && !style_is_none_; }
  // Music guidance needs the lanes reading the music mean (the style one, and the "none" one if guidance
  // is on too).
  bool uses_music_guidance() const { return music_guidance() != 1.0f; }
  // Before a step: starts each lane this step needs that did not step last time from the history closest
  // to it (its missed steps cannot be replayed), with its own style; then records which lanes step.
  void PrepareLanes();
  // The music token the music-mean lanes read this step, given the song's (`music`, 4F): the model's music
  // mean, or with Model::music_guidance_features the song's token with those columns the mean. Valid until
  // the next step.
  const float* MeanMusicToken(const float* music);
  // The row of the largest-weight style of a (validated) style mix, a style named twice counting with its
  // summed weight, the first of equals ("none" for an empty mix); ApplyStyle's choice for the metre, dance
  // period and period lock.
  int TopStyleRow(const std::vector<std::pair<std::string, float>>& style) const;
  // Whether every entry of a (validated) style mix with a weight is "none" (an empty mix is "none").
  bool StyleIsNone(const std::vector<std::pair<std::string, float>>& style) const;
  // Pointers to this step's music token (4F) and PRE (P), valid until the next PushAudio.
  void StepInputs(const float** music, const float** pre);
  // One lane's logits of a step (upper, lower; K each); null when the lane did not step.
  struct LaneLogits {
    const float* u = nullptr;
    const float* l = nullptr;
  };
  // After the model ran: sample this step's codes from the lane logits (style guidance, music guidance and
  // the period lock applied if on). The lanes: conditional (style, music), unconditional (none, music),
  // music-mean conditional and music-mean unconditional.
  void SampleCodes(const LaneLogits& cond, const LaneLogits& uncond, const LaneLogits& music_cond,
                   const LaneLogits& music_uncond);
  // After the VQ decoders ran: reconstructs and queues this step's frames ((45, 4) and (31, 4) features).
  void EmitFrames(const Eigen::Ref<const Eigen::MatrixXf>& upper, const Eigen::Ref<const Eigen::MatrixXf>& lower);
  // Tempo-normalised models: emits every real frame whose warped poses are decoded.
  void EmitWarpedFrames();
  // An emitted frame's last stage: the foot lock (if on) on its projected positions, then its rotations.
  void FinishFrame(PoseFrame& frame);
  bool warped() const { return model_->tempo_reference_bpm() > 0.0; }
  // Adds the period lock's bias toward the code lock_lag(stream) steps ago to `logits` of `stream` (0 upper).
  void ApplyPeriodLock(int stream, absl::Span<float> logits);
  // Whether `stream` moved over its last lock_lag(stream) steps (at least half of them distinct codes).
  bool PeriodMoves(int stream);
  // Whether the body turned by more than kPeriodLockMaxTurn over the last lock_lag(1) steps (the lower
  // body's lock does not repeat such a period).
  bool PeriodTurned() const;
  // Whether the crouch guard holds the lower body to standing codes this step.
  bool CrouchGuardActive() const;
  // The period lock's lag of `stream` in whole steps: the model's period_lock_periods(stream) times one
  // period in whole steps (>= 1), so a lower body locked two periods back stays in phase with an upper body
  // locked one period back (two periods of 7.5 steps are 2 x 8 = 16 steps, not 15).
  size_t lock_lag(int stream) const {
    return static_cast<size_t>(model_->period_lock_periods(stream)) *
           static_cast<size_t>(std::max(1.0, std::round(period_steps_)));
  }
  WarpState NewWarpState() const;

  std::shared_ptr<const Model> model_;
  SessionOptions options_;
  SamplingOptions sampling_;
  std::vector<std::pair<std::string, float>> style_;
  bool style_is_none_ = true;  // every weighted row of style_ is "none"
  std::mt19937_64 generator_;
  std::unique_ptr<audio::AudioFrontEnd> front_end_;
  audio::FeatureFrames popped_;            // scratch
  std::vector<float> pending_features_;    // (frames, F) not yet consumed, from frame first_pending_frame_
  std::vector<float> pending_pre_;         // (frames, P)
  int64_t first_pending_frame_ = 0;
  int64_t frames_total_ = 0;               // feature frames received from the front end
  int64_t frames_limit_ = -1;              // after EndOfAudio: frames that count (whole periods)
  bool ended_ = false;
  std::vector<float> music_token_;  // (4F) scratch
  SequenceState cond_;
  SequenceState uncond_;          // style "none", used when guidance != 1
  // Music guidance's lanes, reading the music mean: the style's, and "none"'s when guidance is on too.
  // Empty until first needed (most sessions never use them).
  SequenceState music_cond_;
  SequenceState music_uncond_;
  // Whether each lane stepped at the last step (PrepareLanes).
  bool uncond_live_ = false, music_cond_live_ = false, music_uncond_live_ = false;
  int upper_code_ = 0, lower_code_ = 0;
  VqDecoderState upper_state_, lower_state_;
  PoseReconstructor reconstructor_;
  PoseState pose_;
  FootLock foot_lock_;
  FootLockState foot_lock_state_;  // carried over emitted (real-time) frames
  WarpState warp_;
  double style_reference_bpm_ = 0.0;  // the current style's reference tempo (tempo-normalised models)
  double bar_frames_ = 0.0;           // bar clock period in warped frames (0 = no bar clock)
  double period_steps_ = 0.0;         // the style's dance period in warped steps (0 = unknown: no lock)
  float style_period_lock_ = 0.0f;    // the top style's default period lock weight (Model::StylePeriodLock)
  std::deque<std::pair<int, int>> code_history_;  // (upper, lower) codes of the last steps, oldest first
  std::deque<double> heading_history_;            // pose_.yaw at the start of the last steps, oldest first
  double crouch_load_ = 0.0;      // leaky count of crouched decoded frames (UpdateCrouchGuard)
  bool crouch_guard_on_ = false;  // the load passed kCrouchGuardOn and has not decayed below kCrouchGuardOff
  SamplerScratch sampler_;
  std::vector<float> guided_u_, guided_l_;  // (K) scratch
  std::vector<float> music_u_, music_l_;    // (K) scratch of music guidance
  std::vector<float> mean_token_;           // (4F) the music-mean lanes' token when only some columns are the mean
  Eigen::VectorXf lock_sim_;                // (K) scratch of the period lock
  std::vector<uint8_t> lock_seen_;          // (K) scratch of PeriodMoves
  std::vector<PoseFrame> output_;
};

// Whether `stream` (0 upper, 1 lower) moved over the last `lag` entries of a code history (oldest first):
// at least half of them, and at least 2, distinct codes. The period lock applies to a stream only then. `seen` is optional
// scratch (codebook_size entries).
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
// back at once (its own autoregressive drift; docs/training.md).
inline constexpr double kCrouchDecayFrames = 900.0;
inline constexpr double kCrouchGuardOn = 120.0;
inline constexpr double kCrouchGuardOff = 60.0;

// One decoded frame's update of the crouch guard's state (load and whether the guard is on).
void UpdateCrouchGuard(bool crouched, double* load, bool* active);

// Advances each session by one step with one pass over the weights for all of them (every Linear is a
// matrix-matrix product over the batch). Every session must have StepsReady() > 0 (FailedPrecondition
// otherwise, and then no session advances); a session must not appear twice. Uses a per-thread workspace.
absl::Status StepBatch(absl::Span<Session* const> sessions);

}  // namespace dance::engine

#endif  // DANCE_ENGINE_RUNTIME_SESSION_H_
