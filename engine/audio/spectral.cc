#include "engine/audio/spectral.h"

#include <fftw3.h>

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <mutex>

#include "absl/base/internal/raw_logging.h"

namespace dance::engine::audio {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr float kPowerFloor = 1e-10f;  // -100 dB

// One r2c plan for every analyzer. Created under a mutex on aligned scratch arrays; executed with
// fftwf_execute_dft_r2c on other arrays of the same (fftwf_malloc) alignment.
fftwf_plan SharedPlan() {
  static std::mutex mu;
  static fftwf_plan plan = nullptr;
  std::lock_guard<std::mutex> lock(mu);
  if (plan == nullptr) {
    float* in = fftwf_alloc_real(kWindowSamples);
    fftwf_complex* out = fftwf_alloc_complex(kFftBins);
    plan = fftwf_plan_dft_r2c_1d(kWindowSamples, in, out, FFTW_ESTIMATE);
    ABSL_RAW_CHECK(plan != nullptr, "FFTW could not plan the r2c FFT");
    fftwf_free(in);
    fftwf_free(out);
  }
  return plan;
}

SpectralTables BuildTables() {
  SpectralTables t;
  double window_sum = 0.0;
  for (int i = 0; i < kWindowSamples; ++i) {
    t.window[i] = static_cast<float>(0.5 - 0.5 * std::cos(2.0 * kPi * i / kWindowSamples));
    window_sum += t.window[i];
  }
  t.power_scale = static_cast<float>(4.0 / (window_sum * window_sum));
  for (int k = 0; k < kFftBins; ++k)
    t.bin_hz[k] = static_cast<float>(k * kSampleRate / double(kWindowSamples));

  // Slaney mel filterbank from 0 Hz to Nyquist, area-normalised (librosa's default "slaney" norm).
  const double mel_lo = HzToMel(0.0), mel_hi = HzToMel(kSampleRate / 2.0);
  std::array<double, kNumMelBands + 2> edges;
  for (int i = 0; i < kNumMelBands + 2; ++i) {
    edges[i] = MelToHz(mel_lo + (mel_hi - mel_lo) * i / (kNumMelBands + 1));
  }
  for (int b = 0; b < kNumMelBands; ++b) {
    const double lo = edges[b], mid = edges[b + 1], hi = edges[b + 2];
    const double norm = 2.0 / (hi - lo);
    int first = -1;
    std::vector<float> w;
    for (int k = 0; k < kFftBins; ++k) {
      const double f = t.bin_hz[k];
      const double v = std::max(0.0, std::min((f - lo) / (mid - lo), (hi - f) / (hi - mid)));
      if (v > 0.0) {
        if (first < 0) first = k;
        w.resize(k - first + 1, 0.0f);
        w[k - first] = static_cast<float>(v * norm);
      }
    }
    t.mel_begin[b] = std::max(first, 0);
    t.mel_weights[b] = std::move(w);
  }

  t.dct.resize(kNumMfcc * kNumMelBands);
  for (int c = 0; c < kNumMfcc; ++c) {
    const double scale = c == 0 ? std::sqrt(1.0 / kNumMelBands) : std::sqrt(2.0 / kNumMelBands);
    for (int b = 0; b < kNumMelBands; ++b) {
      t.dct[c * kNumMelBands + b] =
          static_cast<float>(scale * std::cos(kPi * c * (b + 0.5) / kNumMelBands));
    }
  }

  // Chroma: each bin between ~55 Hz and ~5 kHz feeds the pitch classes near its pitch, with a
  // Gaussian of at least half a semitone (wider where a bin spans more than a semitone), times an
  // octave weighting centred on A4 (two octaves standard deviation).
  t.chroma.assign(kNumChroma * kFftBins, 0.0f);
  const double bin_hz = kSampleRate / double(kWindowSamples);
  for (int k = 1; k < kFftBins; ++k) {
    const double f = t.bin_hz[k];
    if (f < 55.0 || f > 5000.0) continue;
    const double midi = 69.0 + 12.0 * std::log2(f / 440.0);
    const double width = 12.0 * std::log2((f + 0.5 * bin_hz) / std::max(1.0, f - 0.5 * bin_hz));
    const double sigma = std::max(0.5, 0.5 * width);
    const double octave = (midi - 69.0) / 12.0;
    const double octave_weight = std::exp(-0.5 * (octave / 2.0) * (octave / 2.0));
    for (int c = 0; c < kNumChroma; ++c) {
      // Pitch class 0 = C (MIDI 60 % 12 == 0). Circular distance in semitones.
      double d = std::fmod(midi - c, 12.0);
      if (d < 0) d += 12.0;
      if (d > 6.0) d -= 12.0;
      t.chroma[c * kFftBins + k] =
          static_cast<float>(octave_weight * std::exp(-0.5 * (d / sigma) * (d / sigma)));
    }
  }
  t.chroma_begin = kFftBins;
  t.chroma_end = 0;
  for (int k = 0; k < kFftBins; ++k) {
    for (int c = 0; c < kNumChroma; ++c) {
      if (t.chroma[c * kFftBins + k] != 0.0f) {
        t.chroma_begin = std::min(t.chroma_begin, k);
        t.chroma_end = std::max(t.chroma_end, k + 1);
      }
    }
  }
  if (t.chroma_end <= t.chroma_begin) t.chroma_begin = t.chroma_end = 0;
  return t;
}

}  // namespace

double HzToMel(double hz) {
  constexpr double kMinLogHz = 1000.0, kMinLogMel = 15.0,
                   kLogStep = 0.06875177742094912;  // ln(6.4)/27
  if (hz < kMinLogHz) return hz / (200.0 / 3.0);
  return kMinLogMel + std::log(hz / kMinLogHz) / kLogStep;
}

double MelToHz(double mel) {
  constexpr double kMinLogHz = 1000.0, kMinLogMel = 15.0, kLogStep = 0.06875177742094912;
  if (mel < kMinLogMel) return mel * (200.0 / 3.0);
  return kMinLogHz * std::exp(kLogStep * (mel - kMinLogMel));
}

const SpectralTables& GetSpectralTables() {
  static const SpectralTables* tables = new SpectralTables(BuildTables());
  return *tables;
}

SpectralAnalyzer::SpectralAnalyzer()
    : tables_(GetSpectralTables()),
      fft_in_(fftwf_alloc_real(kWindowSamples)),
      fft_out_(fftwf_alloc_complex(kFftBins)) {
  ABSL_RAW_CHECK(fft_in_ != nullptr && fft_out_ != nullptr, "fftwf_alloc failed");
  SharedPlan();
}

SpectralAnalyzer::~SpectralAnalyzer() {
  fftwf_free(fft_in_);
  fftwf_free(fft_out_);
}

void SpectralAnalyzer::Analyze(const float* window, SpectralFrame* out) {
  // Sum of squares in double; Eigen's vectorised reduction (several partial sums) instead of one
  // serial chain of 2048 dependent adds. In double the order changes the result by ~1e-16 relative.
  const double sum_sq = Eigen::Map<const Eigen::VectorXf>(window, kWindowSamples).cast<double>().squaredNorm();
  for (int i = 0; i < kWindowSamples; ++i) fft_in_[i] = window[i] * tables_.window[i];
  const double rms = std::sqrt(sum_sq / kWindowSamples);
  out->rms_db = static_cast<float>(std::max(-100.0, 20.0 * std::log10(std::max(rms, 1e-5))));

  auto* spec = static_cast<fftwf_complex*>(fft_out_);
  fftwf_execute_dft_r2c(SharedPlan(), fft_in_, spec);
  for (int k = 0; k < kFftBins; ++k) {
    power_[k] = (spec[k][0] * spec[k][0] + spec[k][1] * spec[k][1]) * tables_.power_scale;
  }

  for (int b = 0; b < kNumMelBands; ++b) {
    const std::vector<float>& w = tables_.mel_weights[b];
    const float* p = power_.data() + tables_.mel_begin[b];
    float acc = 0.0f;
    for (size_t i = 0; i < w.size(); ++i) acc += w[i] * p[i];
    out->log_mel_db[b] = 10.0f * std::log10(std::max(acc, kPowerFloor));
  }
  for (int c = 0; c < kNumMfcc; ++c) {
    const float* d = tables_.dct.data() + c * kNumMelBands;
    float acc = 0.0f;
    for (int b = 0; b < kNumMelBands; ++b) acc += d[b] * out->log_mel_db[b];
    out->mfcc[c] = acc;
  }
  // Only the bins between ~55 Hz and ~5 kHz have chroma weights: skip the all-zero columns.
  using ChromaMatrix = Eigen::Matrix<float, kNumChroma, Eigen::Dynamic, Eigen::RowMajor>;
  const int c0 = tables_.chroma_begin, cn = tables_.chroma_end - tables_.chroma_begin;
  Eigen::Map<Eigen::Matrix<float, kNumChroma, 1>>(out->chroma.data()).noalias() =
      Eigen::Map<const ChromaMatrix, 0, Eigen::OuterStride<>>(tables_.chroma.data() + c0, kNumChroma, cn,
                                                              Eigen::OuterStride<>(kFftBins)) *
      Eigen::Map<const Eigen::VectorXf>(power_.data() + c0, cn);
  float max_chroma = 0.0f;
  for (float c : out->chroma) max_chroma = std::max(max_chroma, c);
  // Below -100 dB of chroma energy the pitch classes are noise: report zeros.
  const float inv = max_chroma > kPowerFloor ? 1.0f / max_chroma : 0.0f;
  for (float& c : out->chroma) c *= inv;
}

}  // namespace dance::engine::audio
