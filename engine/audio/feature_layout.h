// Per-frame feature and PRE layouts of the audio front end: the single definition of every index.
//
// docs/features.md documents the same table with units; the CLI copies it into its JSON metadata.
// A frame is 30 fps: hop kHopSamples at kSampleRate, trailing kWindowSamples window. Frame n uses
// audio samples [0, (n + 1) * kHopSamples) only (lookahead 0).
#ifndef DANCE_ENGINE_AUDIO_FEATURE_LAYOUT_H_
#define DANCE_ENGINE_AUDIO_FEATURE_LAYOUT_H_

namespace dance::engine::audio {

inline constexpr int kSampleRate = 24000;    // Hz, internal rate
inline constexpr int kHopSamples = 800;      // 30 frames per second
inline constexpr int kWindowSamples = 2048;  // trailing analysis window (periodic Hann for spectra)
inline constexpr int kFftBins = kWindowSamples / 2 + 1;
inline constexpr double kFrameRate = static_cast<double>(kSampleRate) / kHopSamples;

inline constexpr int kNumMelBands = 64;
inline constexpr int kNumMfcc = 20;
inline constexpr int kNumChroma = 12;
inline constexpr int kNumTempogram = 48;  // log-spaced tempi kTempogramMinBpm..kTempogramMaxBpm
inline constexpr double kTempogramMinBpm = 60.0;
inline constexpr double kTempogramMaxBpm = 240.0;
inline constexpr int kTempoWindowFrames = 240;  // trailing 8 s of onset envelope

// Feature indices (float32 per frame).
inline constexpr int kMfccBegin = 0;  // 20 MFCC (DCT-II ortho of log-mel dB)
inline constexpr int kDeltaMfccBegin = kMfccBegin + kNumMfcc;    // 20 causal differences
inline constexpr int kChromaBegin = kDeltaMfccBegin + kNumMfcc;  // 12 chroma, max-normalised
inline constexpr int kOnsetIndex = kChromaBegin + kNumChroma;    // spectral flux of log-mel, dB
inline constexpr int kRmsDbIndex = kOnsetIndex + 1;              // RMS in dBFS
inline constexpr int kTempogramBegin = kRmsDbIndex + 1;          // 48 normalised autocorrelations
inline constexpr int kBeatPhaseCosIndex = kTempogramBegin + kNumTempogram;
inline constexpr int kBeatPhaseSinIndex = kBeatPhaseCosIndex + 1;
inline constexpr int kTempoIndex = kBeatPhaseSinIndex + 1;  // log2(tempo_bpm / 120)
inline constexpr int kBarPhaseCosIndex = kTempoIndex + 1;
inline constexpr int kBarPhaseSinIndex = kBarPhaseCosIndex + 1;
inline constexpr int kBeatConfidenceIndex = kBarPhaseSinIndex + 1;  // [0, 1]
inline constexpr int kNumFeatures = kBeatConfidenceIndex + 1;       // 108

// PRE: kPreChannels rhythm channels, sliding DFT over kPreWindow frames, Hann via 3 bins,
// bins 1..16.
inline constexpr int kPreChannels = 4;
inline constexpr int kPreWindow = 64;
inline constexpr int kPreFirstBin = 1;
inline constexpr int kPreNumBins = 16;
inline constexpr double kPreEpsilon =
    1e-3;  // phase = X / sqrt(|X|^2 + eps^2): continuous at |X| -> 0
inline constexpr int kPreDims =
    kPreChannels * kPreNumBins * 2;  // 128, layout [channel][bin][cos, sin]

// Mel bands averaged for the PRE "low-band energy" and "high-band flux" channels.
inline constexpr int kLowBandEnd = 8;      // mel bands [0, 8)  (below ~300 Hz)
inline constexpr int kHighBandBegin = 32;  // mel bands [32, 64) (above ~2.3 kHz)

}  // namespace dance::engine::audio

#endif  // DANCE_ENGINE_AUDIO_FEATURE_LAYOUT_H_
