// Causal tempo and beat tracker over the 30 fps onset-strength envelope.
//
// Per frame it keeps the trailing 8 s of onset strength and computes (all from the past only):
//  - a tempogram: the Hann-windowed, mean-removed autocorrelation r(L) (r(0) = 1) sampled at
//    kNumTempogram log-spaced tempi between 60 and 240 BPM (lag L = 1800 / bpm frames, linear
//    interp.);
//  - a tempo score on a fine log grid (40..250 BPM, 1 % steps): max(0, r(lag)) (high at the beat
//  period
//    and its multiples) times the normalised Fourier magnitude of the envelope at that tempo (high
//    at the beat frequency and its multiples) times a log-normal prior around 120 BPM (0.6 octave
//    std). The product peaks at the true tempo only; scores are smoothed over time (4 s time
//    constant) and the argmax (parabola-refined) picks the tempo octave; the running tempo is then
//    refined to the maximum of the envelope's harmonic sum (harmonics 1-4) within +-3 %, and
//    smoothed;
//  - the beat phase: the phase of the envelope's recent (1.5 s decay) Fourier component at the
//  running
//    tempo, corrected for the onset detector's delay, followed by a phase-locked loop whose phase
//    only moves forward. A beat is emitted when the phase wraps; bar phase counts beats modulo 4
//    (no downbeat detection).
// Phases refer to the time of the newest sample of the frame. Not thread-safe; no allocation after
// construction; the state is a plain copyable struct (snapshot = copy).
#ifndef DANCE_ENGINE_AUDIO_BEAT_TRACKER_H_
#define DANCE_ENGINE_AUDIO_BEAT_TRACKER_H_

#include <array>
#include <cstdint>

#include "engine/audio/feature_layout.h"

namespace dance::engine::audio {

inline constexpr double kTempoGridMinBpm = 40.0;
inline constexpr double kTempoGridMaxBpm = 250.0;
inline constexpr int kTempoGridSize = 185;  // ratio 1.01 between neighbours
inline constexpr int kMaxAcfLag = 46;       // frames; covers 40 BPM (45 frames)

struct BeatTrackerOutput {
  std::array<float, kNumTempogram> tempogram;
  double tempo_bpm = 120.0;
  double beat_phase = 0.0;  // [0, 1): fraction of the beat period elapsed since the last beat
  double bar_phase = 0.0;   // [0, 1)
  double confidence = 0.0;  // [0, 1]: coherence of recent onsets with the running tempo's phase
  bool beat = false;        // a beat happened during this frame
  double beat_offset_frames = 0.0;  // if beat: how many frames before the frame's end it happened
};

struct BeatTrackerState {
  std::array<float, kTempoWindowFrames> onset_ring{};  // onset strength, ring by frame index
  int64_t frames = 0;
  std::array<float, kTempoGridSize> score{};  // smoothed tempo scores
  double tempo_bpm = 120.0;
  bool tempo_locked = false;  // a first estimate exists
  double phase = 0.0;
  int64_t beat_count = 0;
};

class BeatTracker {
 public:
  BeatTracker();
  // Consumes the onset strength of the next frame.
  void Update(float onset, BeatTrackerOutput* out);
  void Reset() { state_ = BeatTrackerState{}; }
  const BeatTrackerState& state() const { return state_; }
  void set_state(const BeatTrackerState& state) { state_ = state; }

 private:
  BeatTrackerState state_;
  // Scratch (not state): the mean-removed trailing envelope, newest first (index = age in frames).
  std::array<float, kTempoWindowFrames> y_;
  std::array<double, kMaxAcfLag + 2> acf_;
  std::array<float, 2 * kTempoGridSize> projection_;  // Fourier projections (re, im) per grid tempo
};

// Onset detector delay used to align phases: a transient at time t peaks in the onset envelope
// about this many frames after t (trailing Hann window: the peak comes when the transient nears the
// centre).
inline constexpr double kOnsetDelayFrames = 1.0;

}  // namespace dance::engine::audio

#endif  // DANCE_ENGINE_AUDIO_BEAT_TRACKER_H_
