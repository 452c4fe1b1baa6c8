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
// Parts: a Session is composed of parts that each own their state and its snapshot: TimeBase (audio
// intake, features, the tempo clock and warped playback), SamplingPolicy (options, style, generator, the
// period lock and crouch guard), SequenceLanes (the model's KV caches and Mamba states per guidance lane,
// the last codes), BodyDecoder (the VQ decoders' histories, the root, the foot lock) and MotionControl
// (the controls: forced and pulled codes, the trajectory's bias, the output compositing). SessionSnapshot is
// the tuple of their states, so a part's new field is snapshotted, restored and reset with no edit here.
//
// Thread safety: a Session is not thread-safe (one owner at a time); different sessions may be used from
// different threads, sharing one Model. StepBatch needs all its sessions to be owned by the caller.
#ifndef DANCE_ENGINE_RUNTIME_SESSION_H_
#define DANCE_ENGINE_RUNTIME_SESSION_H_

#include <cstdint>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/types/span.h"
#include "engine/nn/sampling.h"
#include "engine/runtime/controls.h"
#include "engine/runtime/internal/body_decoder.h"
#include "engine/runtime/internal/motion_control.h"
#include "engine/runtime/model.h"
#include "engine/runtime/pose_frame.h"
#include "engine/runtime/internal/sampling_policy.h"
#include "engine/runtime/internal/sequence_lanes.h"
#include "engine/runtime/style_mix.h"
#include "engine/runtime/internal/time_base.h"

namespace dance::engine {

struct SessionOptions {
  int input_sample_rate = 24000;  // Hz, 8000..96000
  int input_channels = 1;         // 1..8, interleaved; downmixed to mono by averaging
  StyleMix style;                 // empty = "none"; weights >= 0, normalised to sum 1
  uint64_t seed = 0;
  SamplingOptions sampling;
  // Seed motion, given halves, keyframes, inpainting, a trajectory (controls.h); empty = none.
  Controls controls;
};

// Everything a Session remembers, as a copyable value: the parts' states (opaque to callers; valid only for
// a session of the same model and input format).
struct SessionSnapshot {
  int input_sample_rate = 0;
  int input_channels = 0;
  TimeBaseSnapshot time;
  SamplingState sampling;
  LaneState lanes;
  BodyState body;
  MotionControlState control;
  std::vector<PoseFrame> output;  // frames produced and not popped yet
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
  int StepsReady() const { return time_.StepsReady(lanes_.step()); }
  // Advances one step (== StepBatch of this session alone).
  absl::Status Step();
  // Appends the frames produced so far, in order, to `out` and forgets them.
  void PopFrames(std::vector<PoseFrame>* out);
  // Appends the beats the causal tracker found in the audio pushed so far and not popped yet (seconds on
  // the input timeline, ascending) to `out` and forgets them. A beat is known once its audio arrived, so
  // it comes before the frames of its time (those wait for the model's lookahead). They travel in
  // snapshots.
  void PopBeats(std::vector<double>* out) { time_.TakeBeats(out); }

  // Changes the style from the next step on; InvalidArgument for an unknown name or a bad weight.
  absl::Status SetStyle(const StyleMix& style) { return ApplyStyle(style); }
  absl::Status SetSampling(const SamplingOptions& sampling) { return policy_.SetSampling(sampling); }
  // Replaces the controls from the next step on (a new path, a hand-over clip, the latest given poses);
  // the dance's alignment carries on. InvalidArgument for bad controls (nothing changes then). The
  // controls travel in snapshots.
  absl::Status SetControls(const Controls& controls) { return control_.SetControls(controls); }
  // The real (audio-timeline, 30 fps) frames [*first, *last] the next step will emit, as the clock
  // estimates them now: live given motion must reach *last plus ControlLookaheadFrames() before that step
  // runs for its codes to be the ones the whole motion gives.
  void NextStepRealFrames(double* first, double* last) const;
  // How many frames past a step's last frame the VQ encoders read given motion (0 without encoders).
  int ControlLookaheadFrames() const;

  absl::StatusOr<SessionSnapshot> Snapshot() const;
  absl::Status Restore(const SessionSnapshot& snapshot);
  // Back to the state right after Create (same options, seed and style).
  void Reset();

  // Declared model latency in ms (music lookahead; the front end adds none).
  double LatencyMs() const { return model_->LatencyMs(); }
  // Steps taken so far.
  int64_t steps_done() const { return lanes_.step(); }
  // The music token (frames_per_step x kNumFeatures, frame-major) the last step of a tempo-normalised
  // model read (its bar phase is the bar clock's if the model has one); for tests. Empty before the first
  // step and for fixed-rate models.
  const std::vector<float>& last_warped_music_token() const { return time_.last_warped_music_token(); }
  // The period lock weight in effect (SamplingOptions::period_lock, or if negative the model's weight for
  // the top style, Model::StylePeriodLock).
  float period_lock() const { return policy_.period_lock(); }
  // The sampling options as set (negative fields = the model's defaults, resolved per step).
  const SamplingOptions& sampling() const { return policy_.options(); }
  // The style guidance weight in effect (SamplingOptions::guidance, or the model's default if negative).
  float guidance() const { return policy_.guidance(); }
  // The music guidance weight in effect (SamplingOptions::music_guidance, or the model's default if negative).
  float music_guidance() const { return policy_.music_guidance(); }
  // The nucleus cut in effect (SamplingOptions::top_p, or the model's default if negative).
  float top_p() const { return policy_.top_p(); }
  // The (upper, lower) codes of the last step (the BOS code K before the first).
  std::pair<int, int> last_codes() const { return lanes_.codes(); }
  // Approximate bytes of per-session state (caches, states, buffers).
  int64_t StateBytes() const;
  const Model& model() const { return *model_; }

 private:
  friend absl::Status StepBatch(absl::Span<Session* const> sessions);
  Session(std::shared_ptr<const Model> model, const SessionOptions& options, TimeBase time, MotionControl control);

  absl::Status ApplyStyle(const StyleMix& style);
  // After the VQ decoders ran: reconstructs and queues this step's frames ((45, 4) and (31, 4) features).
  void EmitFrames(const Eigen::Ref<const Eigen::MatrixXf>& upper, const Eigen::Ref<const Eigen::MatrixXf>& lower);
  // Finishes (foot lock, rotations) the frames of output_ from `first` on.
  void FinishFrames(size_t first);

  std::shared_ptr<const Model> model_;
  SessionOptions options_;
  TimeBase time_;
  SamplingPolicy policy_;
  SequenceLanes lanes_;
  BodyDecoder body_;
  MotionControl control_;
  std::vector<PoseFrame> output_;
};

// Advances each session by one step with one pass over the weights for all of them (every Linear is a
// matrix-matrix product over the batch). Every session must have StepsReady() > 0 (FailedPrecondition
// otherwise, and then no session advances); a session must not appear twice. Uses a per-thread workspace.
absl::Status StepBatch(absl::Span<Session* const> sessions);

}  // namespace dance::engine

#endif  // DANCE_ENGINE_RUNTIME_SESSION_H_
