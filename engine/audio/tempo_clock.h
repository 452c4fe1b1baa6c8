// TempoClock: maps the real 30 fps frame timeline onto a tempo-normalised ("warped") timeline in which
// every song plays at one reference tempo (docs/model.md section 8, design (3); docs/features.md).
//
// A model trained in warped time dances at a fixed number of frames per beat; the engine runs it on
// warped frames and plays its poses back on the real timeline, so the dance follows the music's tempo by
// construction. Real frame n (30 fps) spans warped positions [W_n, W_{n+1}), W_0 = 0,
//   W_{n+1} = W_n + r_n,   r_n = Fold(tempo_n) / reference_bpm,
// where tempo_n is the causal beat tracker's running tempo at frame n (feature `tempo`) and Fold moves it
// by whole octaves into [reference / sqrt 2, reference * sqrt 2) (with hysteresis, so a tempo near the
// edge does not flip between octaves). Warped frame j (an integer) lies in the span of exactly one real
// frame: its *source* frame n (W_n <= j < W_{n+1}), at the continuous real position
// x_j = n + (j - W_n) / r_n. Features of warped frame j are those of its source frame (causal: frame n is
// complete when its span is known); motion in warped time is the real motion sampled at x_j.
//
// Training computes the same mapping with this code (`dance-features --clock`), so the two cannot drift.
//
// Usage:
//   TempoClock clock({.reference_bpm = 105});
//   TempoClock::Span s = clock.Push(tempo_bpm_of_frame_n);   // s.begin = W_n, s.end = W_{n+1}
//   for (int64_t j = s.first_warped; j < s.end_warped; ++j) { /* warped frame j has source n */ }
//
// Copyable value (snapshot = copy); not thread-safe; deterministic (double arithmetic, no state but this).
#ifndef DANCE_ENGINE_AUDIO_TEMPO_CLOCK_H_
#define DANCE_ENGINE_AUDIO_TEMPO_CLOCK_H_

#include <cmath>
#include <cstdint>

#include "engine/audio/feature_layout.h"

namespace dance::engine::audio {

struct TempoClockOptions {
  double reference_bpm = 105.0;     // the tempo of warped time; > 0
  double octave_hysteresis = 0.08;  // keep the current octave while the folded tempo is within 8 % outside
};

class TempoClock {
 public:
  struct Span {
    int64_t frame = 0;         // the real frame n just pushed
    double begin = 0.0;        // W_n
    double end = 0.0;          // W_{n+1}
    double rate = 1.0;         // r_n: warped frames per real frame
    int64_t first_warped = 0;  // warped frames [first_warped, end_warped) have source frame n (may be empty)
    int64_t end_warped = 0;
    // Continuous real position of warped frame j in this span.
    double RealPosition(int64_t j) const { return static_cast<double>(frame) + (j - begin) / rate; }
  };

  explicit TempoClock(const TempoClockOptions& options = {}) : options_(options) {}

  // The running tempo in BPM from the feature frame's `tempo` value (log2(bpm / 120), float32): the one
  // conversion the engine and `dance-features --clock` share.
  static double TempoFromFeature(float log2_tempo_over_120) {
    return 120.0 * std::exp2(static_cast<double>(log2_tempo_over_120));
  }

  // Consumes the running tempo (BPM) of the next real frame; non-finite or non-positive values count as
  // the reference tempo.
  Span Push(double tempo_bpm);
  // Consumes the next real frame's feature row (kNumFeatures), reading its `tempo` column. The engine and
  // `dance-features --clock` (training) both clock from this float32 column, so their warped timelines
  // agree bit for bit.
  Span PushFeatures(const float* features) { return Push(TempoFromFeature(features[kTempoIndex])); }

  // The tempo folded into the reference octave (updates the octave choice).
  double Fold(double tempo_bpm);

  // Changes the reference tempo from the next frame on (a session's style changed); the octave is chosen
  // afresh for the new reference. Position and frame count carry on.
  void SetReference(double reference_bpm) {
    options_.reference_bpm = reference_bpm;
    octave_set_ = false;
  }

  int64_t frames() const { return frames_; }     // real frames pushed
  double position() const { return position_; }  // W of the next real frame
  // Warped frames whose source frame has been pushed: all j < position(), i.e. ceil(position()).
  int64_t warped_frames() const { return next_warped_; }
  const TempoClockOptions& options() const { return options_; }

 private:
  TempoClockOptions options_;
  int64_t frames_ = 0;
  double position_ = 0.0;
  int64_t next_warped_ = 0;
  int octave_ = 0;  // folded = tempo * 2^octave_
  bool octave_set_ = false;
};

// The bar clock of a tempo-normalised model (runtime Model::bar_clock(), docs/model.md section 1): a
// metronome in warped time whose phase replaces the beat tracker's bar phase in the music tokens. Its
// period is beats_per_bar beats at the reference tempo, BarClockFrames warped frames; warped frame j has
// phase frac(j / bar_frames). The engine's session and `dance-features --clock --bar-beats` (training)
// both use these two functions.
double BarClockFrames(int beats_per_bar, double reference_bpm);
// Writes (cos, sin) of 2 pi x frac(warped_frame / bar_frames) into the bar_phase entries of `features`
// (a kNumFeatures row).
void BarClockPhase(int64_t warped_frame, double bar_frames, float* features);

// The tempo fold of a tempo-normalised model (runtime Model::fold_tempo(), docs/model.md section 1): the
// features of a warped frame whose source frame has clock rate r (Span::rate = Fold(tempo) / R) are shown
// as if the song played at the folded reference, i.e. r times slower: the `tempogram` entries move along
// their log-tempo axis by -log2(r) octaves (entry i takes the value at fractional index i + log2(r) / d,
// d = log2(240 / 60) / 47 octaves per entry, linearly interpolated, clamped to the first and last entry)
// and `tempo` becomes tempo - log2(r). The rest of the row is unchanged. The engine's session and
// `dance-features --clock --fold-tempo` (training) both use this function.
void FoldTempoFeatures(double rate, float* features);

// The feature row (kNumFeatures) of warped frame `warped_frame` whose source frame's row is `source` and
// clock rate `rate`: the source row, tempo-folded if `fold_tempo`, with the bar clock's phase if
// bar_frames > 0. The engine's session and `dance-features --clock` (training) both build warped rows
// with it. `out` may not alias `source`.
void WarpedFeatureRow(const float* source, double rate, int64_t warped_frame, bool fold_tempo, double bar_frames,
                      float* out);

}  // namespace dance::engine::audio

#endif  // DANCE_ENGINE_AUDIO_TEMPO_CLOCK_H_
