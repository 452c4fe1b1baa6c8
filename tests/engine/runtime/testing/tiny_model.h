// A small random-weight model written by C++ (independent of the training side's test model), so the
// engine's unit tests can build, corrupt and vary models freely. Tensor names follow
// docs/weights-format.md; values are seeded and deterministic.
//
//   TinyModelOptions opt;  opt.seed = 3;
//   WeightsWriter w = TinyModelWriter(opt);
//   ASSERT_TRUE(w.WriteFile(path).ok());
#ifndef DANCE_TESTS_ENGINE_RUNTIME_TESTING_TINY_MODEL_H_
#define DANCE_TESTS_ENGINE_RUNTIME_TESTING_TINY_MODEL_H_

#include <cstdint>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "engine/nn/weights_writer.h"
#include "engine/runtime/model.h"

namespace dance::engine::testing {

struct TinyModelOptions {
  uint64_t seed = 1;
  int d_model = 16;
  int n_heads = 2;
  int n_base = 1;
  int n_head = 1;
  int attn_window = 4;
  int codebook_size = 16;
  int d_state = 4;
  int vq_width = 8;
  int vq_code_dim = 6;
  int vq_n_res = 1;
  int music_lookahead_steps = 0;
  float scale = 0.3f;  // weight magnitude: large enough that codes vary
  double tempo_reference_bpm = 0.0;  // > 0: metadata time_base {"kind": "tempo", "reference_bpm": ...}
  std::vector<std::pair<std::string, double>> style_reference_bpm;  // time_base.style_reference_bpm
  int bar_clock_beats = 0;  // > 0: time_base.bar_clock.beats_per_bar (with tempo_reference_bpm)
  std::vector<std::pair<std::string, int>> style_beats_per_bar;     // time_base.bar_clock.style_beats_per_bar
  std::string fold_tempo;  // non-empty: time_base.fold_tempo, this JSON text ("true", "false"; others to test errors)
  std::vector<std::pair<std::string, double>> dance_period_beats;   // time_base.dance_period_beats
  double period_lock = -1.0;  // >= 0: time_base.period_lock (the sessions' default lock weight)
  std::vector<std::pair<std::string, double>> style_period_lock;    // time_base.style_period_lock
  double period_lock_sharpness = 0.0;  // != 0: time_base.period_lock_sharpness
  int upper_lock_periods = 0;  // != 0: time_base.period_lock_periods.upper
  int lower_lock_periods = 0;  // != 0: time_base.period_lock_periods.lower
  double guidance = -1.0;     // >= 0: sampling.guidance (the sessions' default style guidance)
  double top_p = -1.0;        // > 0: sampling.top_p (the sessions' default nucleus cut)
  double music_guidance = -1.0;  // >= 0: sampling.music_guidance (the sessions' default music guidance)
  std::vector<std::pair<int, int>> music_guidance_features;  // sampling.music_guidance_features
  double yaw_rate_mean = 0.0; // != 0: the lower decoder's mean yaw rate (radians per frame, channel 29)
  double height_mean = 0.0;   // != 0: the lower decoder's mean pelvis height (metres, channel 30; its std 1)
};

WeightsWriter TinyModelWriter(const TinyModelOptions& options);

// The default training sizes (training/model/config.py): d 128, 4 heads, 2 + 2 blocks, W 32, K 512,
// d_state 16, VQ width 128, code dim 64, 2 res blocks. For benchmarks and memory figures.
TinyModelOptions DefaultSizeOptions();

// Writes the model to a temporary file and loads it (CHECK-fails on error: test helper).
std::shared_ptr<const Model> LoadTinyModel(const TinyModelOptions& options = {});

// A deterministic test signal: clicks on a 120 BPM grid over a low tone, mono, 24 kHz.
std::vector<float> TestAudio(double seconds, int sample_rate = 24000);
// The same at another tempo (clicks every 60 / bpm s).
std::vector<float> ClickAudio(double seconds, double bpm, int sample_rate = 24000);

}  // namespace dance::engine::testing

#endif  // DANCE_TESTS_ENGINE_RUNTIME_TESTING_TINY_MODEL_H_
