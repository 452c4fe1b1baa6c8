// SGMD benchmarks (they print numbers; nothing asserts a speed), on one core:
//   BM_SgmdDenoise        one denoiser call over a whole window (the unit of every sampling step).
//   BM_SgmdEncodeMusic    a window's music encoder and its cross-attention keys and values (once per window).
//   BM_SgmdSampleWindow/S/G  DDIM over one window with S steps and guidance G / 10 (G = 10: one pass per step,
//                         G = 20: two), known values on the first half of the frames (a window after the first);
//                         "time_per_step" is the cost per step.
// The model is models/sgmd.dncw when it exists (or $DANCE_BENCH_SGMD_MODEL); otherwise a model of the shipped
// size (training/model/sgmd.py SGMDConfig: d 192, 4 heads, 4 + 2 blocks, 150 frames) with random weights,
// written to a temporary file. A whole dance is ~10 windows per minute of song, each one SampleWindow.
//
//   build/bin/sgmd_bench --benchmark_filter=BM_Sgmd
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <random>
#include <string>
#include <vector>

#include "benchmark/benchmark.h"
#include "engine/diffusion/ddim.h"
#include "engine/diffusion/sgmd_model.h"
#include "engine/nn/weights_file.h"
#include "engine/nn/weights_writer.h"

namespace dance::engine {
namespace {

// Metadata of the shipped size; the skeleton, features and styles borrowed from the tiny SGMD test model.
nlohmann::json ShippedMetadata() {
  absl::StatusOr<WeightsFile> tiny = WeightsFile::Load("models/sgmd-tiny.dncw");
  if (!tiny.ok()) {
    std::fprintf(stderr, "need models/sgmd-tiny.dncw for the skeleton (run from the source root): %s\n",
                 std::string(tiny.status().message()).c_str());
    std::exit(1);
  }
  nlohmann::json md = tiny->metadata();
  const SgmdConfig c;  // the shipped sizes
  md["model_id"] = "sgmd-random-shipped-size";
  md["sgmd"] = {{"feature_dim", c.feature_dim}, {"pre_dim", c.pre_dim},         {"pose_dim", c.pose_dim},
                {"frames", c.frames},           {"frames_per_token", c.frames_per_token},
                {"d_model", c.d_model},         {"n_heads", c.n_heads},         {"n_layers", c.n_layers},
                {"n_music_layers", c.n_music_layers}, {"n_styles", c.n_styles}, {"style_dim", c.style_dim},
                {"style_mod_r", 1.0 / std::sqrt(static_cast<double>(c.d_model))},
                {"diffusion_steps", c.diffusion_steps}};
  md["sampling"] = {{"steps", 50}, {"guidance", 1.0}, {"overlap_frames", c.frames / 2}};
  return md;
}

// Every tensor of docs/diffusion.md section 7 with random values (matrices ~ N(0, 1/in), norms ~ 1).
WeightsWriter RandomShippedModel() {
  const SgmdConfig c;
  WeightsWriter w(ShippedMetadata());
  std::mt19937 gen(1);
  std::normal_distribution<float> normal(0.0f, 1.0f);
  auto add = [&](const std::string& name, std::vector<int64_t> shape, float scale, float offset = 0.0f) {
    int64_t n = 1;
    for (int64_t s : shape) n *= s;
    std::vector<float> v(n);
    for (float& x : v) x = offset + scale * normal(gen);
    w.Add("sgmd." + name, shape, v);
  };
  const int64_t d = c.d_model, n = c.tokens(), kd = c.frames_per_token * c.pose_dim, ff = 4 * d;
  auto linear = [&](const std::string& name, int64_t out, int64_t in) {
    add(name + ".weight", {out, in}, 1.0f / std::sqrt(static_cast<float>(in)));
    add(name + ".bias", {out}, 0.02f);
  };
  auto norm = [&](const std::string& name) {
    add(name + ".weight", {d}, 0.1f, 1.0f);
    add(name + ".bias", {d}, 0.02f);
  };
  auto attention = [&](const std::string& name) {
    for (const char* p : {"q", "k", "v", "o"}) linear(name + "." + p, d, d);
  };
  std::vector<float> abar(c.diffusion_steps);
  double prev = 1.0;
  for (int t = 0; t < c.diffusion_steps; ++t) {  // the cosine schedule (s = 0.008, betas clipped at 0.999)
    auto f = [&](int i) { return std::pow(std::cos((i / 1000.0 + 0.008) / 1.008 * M_PI / 2), 2); };
    prev *= 1.0 - std::min(0.999, 1.0 - f(t + 1) / f(t));
    abar[t] = static_cast<float>(prev);
  }
  w.Add("sgmd.alphas_cumprod", {c.diffusion_steps}, abar);
  add("pose_mean", {c.pose_dim}, 0.3f);
  add("pose_std", {c.pose_dim}, 0.0f, 1.0f);
  add("music_mean", {c.feature_dim}, 0.3f);
  add("music_std", {c.feature_dim}, 0.0f, 1.0f);
  linear("motion_in", d, kd);
  add("motion_pos", {n, d}, 0.02f);
  linear("music_in", d, c.music_dim());
  add("music_pos", {n, d}, 0.02f);
  for (int i = 0; i < c.n_music_layers; ++i) {
    const std::string p = "music_blocks." + std::to_string(i);
    norm(p + ".norm1");
    norm(p + ".norm2");
    attention(p + ".attn");
    linear(p + ".ffn.fc1", ff, d);
    linear(p + ".ffn.fc2", d, ff);
  }
  norm("music_norm");
  add("music_null", {n, d}, 0.02f);
  linear("music_pool", d, d);
  linear("time_fc1", ff, d);
  linear("time_fc2", d, ff);
  add("style_table", {c.n_styles + 1, c.style_dim}, 0.5f);
  for (int i = 0; i < c.n_layers; ++i) {
    const std::string p = "blocks." + std::to_string(i);
    linear(p + ".style", d, c.style_dim);
    norm(p + ".norm1");
    norm(p + ".norm2");
    norm(p + ".norm3");
    attention(p + ".self_attn");
    attention(p + ".cross_attn");
    linear(p + ".ffn.fc1", ff, d);
    linear(p + ".ffn.fc2", d, ff);
    linear(p + ".film", 6 * d, d);
  }
  norm("norm_f");
  linear("out", kd, d);
  return w;
}

std::shared_ptr<const SgmdModel> BenchModel() {
  static std::shared_ptr<const SgmdModel> model = [] {
    const char* env = std::getenv("DANCE_BENCH_SGMD_MODEL");
    std::string path = env != nullptr ? env : "models/sgmd.dncw";
    if (!std::filesystem::exists(path)) {
      path = (std::filesystem::temp_directory_path() / "sgmd_bench_random.dncw").string();
      if (absl::Status s = RandomShippedModel().WriteFile(path); !s.ok()) {
        std::fprintf(stderr, "cannot write %s: %s\n", path.c_str(), std::string(s.message()).c_str());
        std::exit(1);
      }
    }
    absl::StatusOr<std::shared_ptr<const SgmdModel>> m = SgmdModel::Load(path);
    if (!m.ok()) {
      std::fprintf(stderr, "cannot load %s: %s\n", path.c_str(), std::string(m.status().message()).c_str());
      std::exit(1);
    }
    const SgmdConfig& c = (*m)->config();
    std::fprintf(stderr, "model: %s (%s): d %d, %d heads, %d + %d blocks, %d frames, %d tokens\n", path.c_str(),
                 (*m)->model_id().c_str(), c.d_model, c.n_heads, c.n_layers, c.n_music_layers, c.frames, c.tokens());
    return *m;
  }();
  return model;
}

struct Window {
  Eigen::MatrixXf music, noise;
  Eigen::VectorXf style;
  WindowKnown known;
};

Window MakeWindow(const SgmdModel& m) {
  const SgmdConfig& c = m.config();
  Window w;
  std::mt19937_64 gen(3);
  w.music.resize(c.music_dim(), c.tokens());
  FillStandardNormal(gen, &w.music);
  w.noise.resize(c.pose_dim, c.frames);
  FillStandardNormal(gen, &w.noise);
  w.style = m.StyleVector(Eigen::VectorXf::Unit(c.n_styles + 1, 0));
  w.known.values.resize(c.pose_dim, c.frames);
  FillStandardNormal(gen, &w.known.values);
  w.known.mask = Eigen::MatrixXf::Zero(c.pose_dim, c.frames);
  w.known.mask.leftCols(c.frames / 2).setOnes();
  return w;
}

void BM_SgmdDenoise(benchmark::State& state) {
  const SgmdModel& m = *BenchModel();
  const Window w = MakeWindow(m);
  const SgmdModel::Context c = m.EncodeMusic(w.music);
  Eigen::MatrixXf x0;
  for (auto _ : state) {
    m.Denoise(w.noise, 500, c, w.style, &x0);
    benchmark::DoNotOptimize(x0.data());
  }
}
BENCHMARK(BM_SgmdDenoise)->Unit(benchmark::kMillisecond);

void BM_SgmdEncodeMusic(benchmark::State& state) {
  const SgmdModel& m = *BenchModel();
  const Window w = MakeWindow(m);
  for (auto _ : state) {
    SgmdModel::Context c = m.EncodeMusic(w.music);
    benchmark::DoNotOptimize(c.tokens.data());
  }
}
BENCHMARK(BM_SgmdEncodeMusic)->Unit(benchmark::kMillisecond);

void BM_SgmdSampleWindow(benchmark::State& state) {
  const SgmdModel& m = *BenchModel();
  const Window w = MakeWindow(m);
  const SgmdModel::Context c = m.EncodeMusic(w.music);
  const SgmdModel::Context none = m.NullContext();
  DdimOptions opt;
  opt.steps = static_cast<int>(state.range(0));
  opt.guidance = static_cast<float>(state.range(1)) / 10.0f;
  for (auto _ : state) {
    Eigen::MatrixXf x = SampleWindow(m, c, none, w.style, w.noise, opt, &w.known);
    benchmark::DoNotOptimize(x.data());
  }
  state.counters["time_per_step"] = benchmark::Counter(opt.steps * static_cast<double>(state.iterations()),
                                                       benchmark::Counter::kIsRate | benchmark::Counter::kInvert);
}
BENCHMARK(BM_SgmdSampleWindow)->Args({50, 10})->Args({50, 20})->Unit(benchmark::kMillisecond)->MinTime(2.0);

}  // namespace
}  // namespace dance::engine

BENCHMARK_MAIN();
