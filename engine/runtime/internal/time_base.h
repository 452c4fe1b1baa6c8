// TimeBase: a session's audio intake and clock. It owns the audio front end (resampler, causal features,
// incremental PRE), the feature frames no step has consumed yet, the end-of-audio limits, and for a
// tempo-normalised model (Model::tempo_reference_bpm() > 0; docs/model.md section 8) the tempo clock that
// maps real frames onto warped ones, the bar clock, and the decoded warped poses waiting to be played back
// on the real 30 fps timeline.
//
// Input side: step t reads the music token of period t + music_lookahead_steps (Inputs); a step is ready
// once that token's audio has fully arrived (StepsReady). Warped models gather each warped frame's features
// from its source frame (with the tempo fold and the bar clock if the model has them).
// Output side (warped models): the session hands each decoded warped pose to AddWarpedPose; EmitWarped
// appends every real frame m whose warped poses around W_m are decoded (linear interpolation, then bone
// projection) and leaves the frame's last stage (foot lock, rotations) to the caller.
//
// Usage (inside Session):
//   absl::StatusOr<TimeBase> t = TimeBase::Create(model, 44100, 2);
//   t->SetStyle(style);
//   t->PushFloat(chunk, &frames);           // warped models may emit frames here
//   while (t->StepsReady(step) > 0) { t->Inputs(step, &music, &pre); ... }
//
// State: every field that changes lives in TimeBaseState (plus the front end's own snapshot), so
// Snapshot/Restore/Reset cover it by construction. Not thread-safe (owned by one Session).
#ifndef DANCE_ENGINE_RUNTIME_INTERNAL_TIME_BASE_H_
#define DANCE_ENGINE_RUNTIME_INTERNAL_TIME_BASE_H_

#include <array>
#include <cstdint>
#include <deque>
#include <memory>
#include <utility>
#include <vector>

#include "Eigen/Core"
#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/types/span.h"
#include "engine/audio/audio_front_end.h"
#include "engine/audio/tempo_clock.h"
#include "engine/runtime/model.h"
#include "engine/runtime/pose_frame.h"
#include "engine/runtime/style_mix.h"
#include "engine/vq/pose_reconstructor.h"

namespace dance::engine {

// The tempo-normalised time base (unused for fixed-rate models); copyable.
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

struct TimeBaseState {
  std::vector<float> pending_features;  // (frames, F) not consumed yet, from first_pending_frame
  std::vector<float> pending_pre;       // (frames, P)
  int64_t first_pending_frame = 0;
  int64_t frames_total = 0;             // feature frames received from the front end
  int64_t frames_limit = -1;            // after End: frames that count (whole periods)
  bool ended = false;
  WarpState warp;
  double bar_frames = 0.0;              // bar clock period in warped frames (0 = no bar clock)
  std::vector<double> beats_s;          // beats the tracker found and TakeBeats has not handed out, s
};

struct TimeBaseSnapshot {
  audio::AudioFrontEndSnapshot front_end;
  TimeBaseState state;
};

class TimeBase {
 public:
  // InvalidArgument for a rate outside [8000, 96000] or channels outside [1, 8] (the front end's checks).
  // The clock has no reference tempo until SetStyle.
  static absl::StatusOr<TimeBase> Create(const Model& model, int sample_rate, int channels);
  TimeBase(TimeBase&&) = default;
  TimeBase& operator=(TimeBase&&) = default;

  // Interleaved PCM at the input rate (a multiple of the channel count); FailedPrecondition after End.
  // Warped models append the real frames that became ready to `out` (positions projected; not finished).
  absl::Status PushFloat(absl::Span<const float> interleaved, std::vector<PoseFrame>* out);
  absl::Status PushInt16(absl::Span<const int16_t> interleaved, std::vector<PoseFrame>* out);
  // No more audio: flushes the resampler, pads the last period with silence, fixes the limits.
  void End(std::vector<PoseFrame>* out);
  bool ended() const { return state_.ended; }

  // Steps ready after `steps_done` steps were taken.
  int StepsReady(int64_t steps_done) const;
  // Step `step`'s music token (frames_per_step x F) and PRE (P), valid until the next Push or Inputs.
  void Inputs(int64_t step, const float** music, const float** pre);
  // After step `next_step - 1` was decoded: forgets the feature frames no later step reads.
  void Forget(int64_t next_step);

  // Warped models: queues the next decoded warped pose (root-integrated, bone-projected) with its codes,
  // returning its slot to be written; EmitWarped then appends every real frame now ready to `out`.
  std::array<Eigen::Vector3f, 24>& AddWarpedPose(std::pair<int, int> codes);
  void EmitWarped(std::vector<PoseFrame>* out);

  // Appends the beats detected since the last call (seconds on the input timeline, ascending; the causal
  // tracker's, as the audio that shows them arrives) to `out` and forgets them.
  void TakeBeats(std::vector<double>* out);

  // A new style from the next frame on: its reference tempo (the clock's octave is chosen afresh when it
  // changes) and bar clock.
  void SetStyle(const ResolvedStyle& style);

  bool warped() const { return model_->tempo_reference_bpm() > 0.0; }
  // The real frames step `step` will emit, [*first, *last], and the clock's rate (warped frames per real
  // frame) then: its warped period's frames mapped through the clock as far as the step's own music token
  // reached, extrapolated at that token's rate beyond (so the answer does not depend on how much more
  // audio has arrived: chunking stays invisible). Fixed rate: the period's own frames, rate 1.
  void EmittedRealSpan(int64_t step, double* first, double* last, double* rate) const;
  // The music token the last step of a warped model read (empty before the first and for fixed rate).
  const std::vector<float>& last_warped_music_token() const { return music_token_; }
  const TimeBaseState& state() const { return state_; }

  TimeBaseSnapshot Snapshot() const;
  // InvalidArgument if the front end's input format differs; nothing changes then.
  absl::Status Restore(const TimeBaseSnapshot& snapshot);
  // Back to a fresh stream with `style`'s clock.
  void Reset(const ResolvedStyle& style);
  int64_t Bytes() const;

 private:
  TimeBase(const Model& model, std::unique_ptr<audio::AudioFrontEnd> front_end);
  TimeBaseState FreshState(const ResolvedStyle& style) const;
  // Moves the front end's finished frames into the pending buffers (and through the clock).
  void CollectFrames(std::vector<PoseFrame>* out);

  const Model* model_;
  PoseReconstructor reconstructor_;  // bone projection of interpolated frames
  std::unique_ptr<audio::AudioFrontEnd> front_end_;
  TimeBaseState state_;
  audio::FeatureFrames popped_;     // scratch
  std::vector<float> music_token_;  // (4F) scratch
};

}  // namespace dance::engine

#endif  // DANCE_ENGINE_RUNTIME_INTERNAL_TIME_BASE_H_
