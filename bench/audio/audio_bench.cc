// Throughput of the audio front end on one core: seconds of audio processed per second of CPU
// (the "x_realtime" counter). Features and PRE are always computed together (one pass).
#include <cmath>
#include <random>
#include <vector>

#include "benchmark/benchmark.h"
#include "engine/audio/audio_front_end.h"
#include "engine/audio/incremental_pre.h"

namespace dance::engine::audio {
namespace {

std::vector<float> Music(double seconds, int rate, int channels) {
  std::mt19937 gen(1);
  std::normal_distribution<float> noise(0.0f, 0.05f);
  const size_t n = static_cast<size_t>(seconds * rate);
  std::vector<float> x(n * channels);
  for (size_t i = 0; i < n; ++i) {
    const double t = static_cast<double>(i) / rate;
    const float v =
        static_cast<float>(0.3 * std::sin(2 * M_PI * 220 * t) +
                           0.4 * std::exp(-std::fmod(t, 0.5) * 20) * std::sin(2 * M_PI * 60 * t)) +
        noise(gen);
    for (int c = 0; c < channels; ++c) x[i * channels + c] = v;
  }
  return x;
}

// Args: input rate, channels, chunk size in frames.
void BM_FrontEnd(benchmark::State& state) {
  const int rate = static_cast<int>(state.range(0));
  const int channels = static_cast<int>(state.range(1));
  const size_t chunk = static_cast<size_t>(state.range(2));
  constexpr double kSeconds = 10.0;
  const std::vector<float> audio = Music(kSeconds, rate, channels);
  auto fe = *AudioFrontEnd::Create({rate, channels});
  FeatureFrames frames;
  for (auto _ : state) {
    fe->Reset();
    for (size_t start = 0; start < audio.size(); start += chunk * channels) {
      const size_t n = std::min(chunk * channels, audio.size() - start);
      benchmark::DoNotOptimize(fe->PushFloat(absl::MakeConstSpan(audio.data() + start, n)));
      fe->PopFrames(&frames);
    }
    benchmark::DoNotOptimize(frames.features.data());
  }
  state.counters["x_realtime"] = benchmark::Counter(
      kSeconds * static_cast<double>(state.iterations()), benchmark::Counter::kIsRate);
}
BENCHMARK(BM_FrontEnd)
    ->Args({24000, 1, 4096})
    ->Args({24000, 1, 800})
    ->Args({44100, 2, 4096})
    ->Args({48000, 2, 480})
    ->Args({16000, 1, 320})
    ->Unit(benchmark::kMillisecond);

void BM_IncrementalPreOnly(benchmark::State& state) {
  IncrementalPre pre;
  std::vector<float> out(kPreDims);
  std::array<float, kPreChannels> in = {0.5f, -2.0f, -4.0f, 0.1f};
  for (auto _ : state) {
    in[0] = in[0] * 0.9f + 0.3f;
    pre.Update(in, absl::MakeSpan(out));
    benchmark::DoNotOptimize(out.data());
  }
  state.counters["frames_per_s"] =
      benchmark::Counter(static_cast<double>(state.iterations()), benchmark::Counter::kIsRate);
}
BENCHMARK(BM_IncrementalPreOnly);

}  // namespace
}  // namespace dance::engine::audio
