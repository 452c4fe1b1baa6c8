// Per-frame spectral analysis of the 24 kHz stream: Hann-windowed 2048-point FFT power spectrum,
// 64-band Slaney mel filterbank, log-mel in dB, MFCC (DCT-II, orthonormal) and chroma.
//
// Internal to dance_audio (FeatureExtractor owns one SpectralAnalyzer). The constant tables are
// built once per process and shared read-only; the FFTW plan is created once under a mutex (FFTW's
// planner is not thread-safe) and executed with the new-array API on each analyzer's own aligned
// buffers, so different analyzers may run concurrently. One analyzer is not thread-safe. No
// allocation after construction.
#ifndef DANCE_ENGINE_AUDIO_SPECTRAL_H_
#define DANCE_ENGINE_AUDIO_SPECTRAL_H_

#include <array>
#include <vector>

#include "engine/audio/feature_layout.h"

namespace dance::engine::audio {

// Shared constant tables (built on first use; thread-safe initialisation).
struct SpectralTables {
  std::array<float, kWindowSamples> window;  // periodic Hann
  float power_scale = 0.0f;                  // makes a full-scale sine's peak bin ~1 (0 dB)
  // Mel filterbank, sparse: band b covers FFT bins [mel_begin[b], mel_begin[b] +
  // mel_weights[b].size()).
  std::array<int, kNumMelBands> mel_begin;
  std::array<std::vector<float>, kNumMelBands> mel_weights;
  std::vector<float> dct;     // (kNumMfcc, kNumMelBands), row-major, DCT-II orthonormal
  std::vector<float> chroma;  // (kNumChroma, kFftBins), row-major
  int chroma_begin = 0;       // bins [chroma_begin, chroma_end) hold every nonzero chroma weight
  int chroma_end = 0;
  std::array<float, kFftBins> bin_hz;
};
const SpectralTables& GetSpectralTables();

// Mel-scale helpers (Slaney: linear below 1 kHz, logarithmic above), exposed for tests.
double HzToMel(double hz);
double MelToHz(double mel);

struct SpectralFrame {
  std::array<float, kNumMelBands> log_mel_db;  // 10 log10(max(mel power, 1e-10)), >= -100 dB
  std::array<float, kNumMfcc> mfcc;
  std::array<float, kNumChroma> chroma;  // max-normalised; all 0 for (near) silence
  float rms_db = -100.0f;                // 20 log10(RMS) of the rectangular window, >= -100 dB
};

class SpectralAnalyzer {
 public:
  SpectralAnalyzer();
  ~SpectralAnalyzer();
  SpectralAnalyzer(const SpectralAnalyzer&) = delete;
  SpectralAnalyzer& operator=(const SpectralAnalyzer&) = delete;

  // `window` holds the last kWindowSamples samples, oldest first.
  void Analyze(const float* window, SpectralFrame* out);

 private:
  const SpectralTables& tables_;
  float* fft_in_;  // (kWindowSamples), fftwf_malloc'd
  void* fft_out_;  // (kFftBins) fftwf_complex, fftwf_malloc'd
  std::array<float, kFftBins> power_;
};

}  // namespace dance::engine::audio

#endif  // DANCE_ENGINE_AUDIO_SPECTRAL_H_
