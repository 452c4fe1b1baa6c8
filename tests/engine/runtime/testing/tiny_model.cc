#include "tests/engine/runtime/testing/tiny_model.h"

#include <array>
#include <cmath>
#include <cstdio>
#include <random>
#include <unistd.h>

#include "absl/strings/str_cat.h"
#include "engine/audio/feature_layout.h"

namespace dance::engine::testing {
namespace {

constexpr const char* kStreams[3] = {"music", "upper", "lower"};
constexpr int kParents[24] = {-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21};
constexpr float kOffsets[24][3] = {
    {0, 0, 0},           {0.0586, -0.0823, -0.0177}, {-0.0603, -0.0905, -0.0135}, {0.0044, 0.1244, -0.0384},
    {0.0435, -0.3865, 0.008}, {-0.0433, -0.3837, -0.0048}, {0.0045, 0.138, 0.0268}, {-0.0148, -0.4269, -0.0374},
    {0.0191, -0.42, -0.0346}, {-0.0023, 0.056, 0.0029}, {0.0411, -0.0603, 0.122}, {-0.0348, -0.0621, 0.1303},
    {-0.0134, 0.2116, -0.0335}, {0.0717, 0.114, -0.0189}, {-0.083, 0.1125, -0.0237}, {0.0101, 0.0889, 0.0504},
    {0.1229, 0.0452, -0.019}, {-0.1132, 0.0469, -0.0085}, {0.2553, -0.0156, -0.0229}, {-0.2601, -0.0144, -0.0313},
    {0.2657, 0.0127, -0.0074}, {-0.2691, 0.0068, -0.006}, {0.0867, -0.0106, -0.0156}, {-0.0888, -0.0087, -0.0101}};

class Builder {
 public:
  Builder(WeightsWriter* w, uint64_t seed, float scale) : w_(w), gen_(seed), scale_(scale) {}
  // `overrides` replace single values after the draws (so the other tensors' draws do not change).
  void Random(const std::string& name, std::vector<int64_t> shape, float scale = -1.0f, float offset = 0.0f,
              const std::vector<std::pair<int, float>>& overrides = {}) {
    int64_t n = 1;
    for (int64_t d : shape) n *= d;
    std::uniform_real_distribution<float> u(-1.0f, 1.0f);
    const float s = scale < 0 ? scale_ : scale;
    std::vector<float> v(n);
    for (float& x : v) x = offset + s * u(gen_);
    for (const auto& [i, value] : overrides) v[i] = value;
    w_->Add(name, shape, v);
  }
  void Const(const std::string& name, std::vector<int64_t> shape, float value) {
    int64_t n = 1;
    for (int64_t d : shape) n *= d;
    w_->Add(name, shape, std::vector<float>(n, value));
  }

 private:
  WeightsWriter* w_;
  std::mt19937_64 gen_;
  float scale_;
};

// The decoder of training/model/vqvae.py: conv, relu, res blocks, then twice (upsample2, conv, relu, res
// blocks), then the output conv. Returns the ops and fills (in, out, k) per conv.
nlohmann::json DecoderOps(const std::string& part, int code_dim, int width, int out_dim, int n_res,
                          std::vector<std::array<int, 3>>* convs) {
  nlohmann::json ops = nlohmann::json::array();
  ops.push_back({{"op", "embed_codes"}});
  auto add_conv = [&](int in, int out, int k, int dilation) {
    const int i = static_cast<int>(convs->size());
    ops.push_back({{"op", "conv"},
                   {"w", absl::StrCat("vq.", part, ".decoder.convs.", i, ".weight")},
                   {"b", absl::StrCat("vq.", part, ".decoder.convs.", i, ".bias")},
                   {"dilation", dilation}});
    convs->push_back({in, out, k});
  };
  auto res_blocks = [&]() {
    int dilation = 1;
    for (int j = 0; j < n_res; ++j, dilation *= 3) {
      ops.push_back({{"op", "res_begin"}});
      ops.push_back({{"op", "relu"}});
      add_conv(width, width, 3, dilation);
      ops.push_back({{"op", "relu"}});
      add_conv(width, width, 1, 1);
      ops.push_back({{"op", "res_end"}});
    }
  };
  add_conv(code_dim, width, 3, 1);
  ops.push_back({{"op", "relu"}});
  res_blocks();
  for (int up = 0; up < 2; ++up) {
    ops.push_back({{"op", "upsample2"}});
    add_conv(width, width, 3, 1);
    ops.push_back({{"op", "relu"}});
    res_blocks();
  }
  add_conv(width, out_dim, 3, 1);
  return ops;
}

}  // namespace

WeightsWriter TinyModelWriter(const TinyModelOptions& o) {
  const int d = o.d_model, k = o.codebook_size, f = audio::kNumFeatures, p = audio::kPreDims;
  const int d_state = o.d_state, d_conv = 4, expand = 2, di = expand * d, r = (d + 15) / 16, ds = 4;
  const int n_styles = 2, width = o.vq_width, code_dim = o.vq_code_dim;
  std::vector<std::array<int, 3>> convs[2];
  nlohmann::json hp = {{"feature_dim", f},      {"pre_dim", p},           {"frames_per_step", 4},
                       {"codebook_size", k},    {"d_model", d},           {"n_heads", o.n_heads},
                       {"n_base", o.n_base},    {"n_head", o.n_head},     {"attn_window", o.attn_window},
                       {"d_state", d_state},    {"d_conv", d_conv},       {"expand", expand},
                       {"n_styles", n_styles},  {"style_dim", ds},        {"style_mod_r", 1.0 / std::sqrt(d)},
                       {"music_lookahead_steps", o.music_lookahead_steps}, {"use_pre", true},
                       {"use_gate", true},      {"shared_mamba", false}};
  nlohmann::json skeleton = {{"parents", nlohmann::json::array()}, {"rest_offsets", nlohmann::json::array()}};
  for (int j = 0; j < 24; ++j) {
    skeleton["parents"].push_back(kParents[j]);
    skeleton["rest_offsets"].push_back({kOffsets[j][0], kOffsets[j][1], kOffsets[j][2]});
  }
  nlohmann::json vq = nlohmann::json::object();
  for (int i = 0; i < 2; ++i) {
    const std::string part = i == 0 ? "upper" : "lower";
    const int in_dim = i == 0 ? 45 : 31;
    vq[part] = {{"in_dim", in_dim}, {"width", width}, {"code_dim", code_dim}, {"codebook_size", k},
                {"n_res", o.vq_n_res}, {"decoder_ops", DecoderOps(part, code_dim, width, in_dim, o.vq_n_res, &convs[i])}};
  }
  nlohmann::json meta = {{"model_id", absl::StrCat("cpp-tiny-", o.seed)}, {"hyperparameters", hp},
                         {"skeleton", skeleton}, {"styles", {"waltz", "tango"}}, {"vq", vq}};
  if (o.tempo_reference_bpm > 0.0) {
    meta["time_base"] = {{"kind", "tempo"}, {"reference_bpm", o.tempo_reference_bpm}};
    for (const auto& [name, bpm] : o.style_reference_bpm) meta["time_base"]["style_reference_bpm"][name] = bpm;
    if (o.bar_clock_beats != 0) {
      meta["time_base"]["bar_clock"] = {{"beats_per_bar", o.bar_clock_beats}};
      for (const auto& [name, beats] : o.style_beats_per_bar) {
        meta["time_base"]["bar_clock"]["style_beats_per_bar"][name] = beats;
      }
    }
    if (!o.fold_tempo.empty()) meta["time_base"]["fold_tempo"] = nlohmann::json::parse(o.fold_tempo);
    for (const auto& [name, beats] : o.dance_period_beats) meta["time_base"]["dance_period_beats"][name] = beats;
    if (o.period_lock >= 0.0) meta["time_base"]["period_lock"] = o.period_lock;
    for (const auto& [name, lock] : o.style_period_lock) meta["time_base"]["style_period_lock"][name] = lock;
    if (o.period_lock_sharpness != 0.0) meta["time_base"]["period_lock_sharpness"] = o.period_lock_sharpness;
    if (o.upper_lock_periods != 0) meta["time_base"]["period_lock_periods"]["upper"] = o.upper_lock_periods;
    if (o.lower_lock_periods != 0) meta["time_base"]["period_lock_periods"]["lower"] = o.lower_lock_periods;
  }
  if (o.guidance >= 0.0) meta["sampling"]["guidance"] = o.guidance;
  if (o.top_p > 0.0) meta["sampling"]["top_p"] = o.top_p;
  if (o.music_guidance >= 0.0) meta["sampling"]["music_guidance"] = o.music_guidance;
  for (const auto& [b, e] : o.music_guidance_features) meta["sampling"]["music_guidance_features"].push_back({b, e});
  WeightsWriter w(meta);
  Builder b(&w, o.seed, o.scale);
  b.Random("seq.music_mean", {4 * f}, 0.1f);
  b.Random("seq.music_std", {4 * f}, 0.2f, 1.0f);
  b.Random("seq.embed.music.weight", {d, 4 * f}, 0.05f);
  b.Random("seq.embed.music.bias", {d});
  b.Random("seq.embed.upper", {k + 1, d}, 1.0f);
  b.Random("seq.embed.lower", {k + 1, d}, 1.0f);
  b.Random("seq.embed.stream", {3, d});
  b.Random("seq.pre.weight", {d, p}, 0.1f);
  b.Random("seq.pre.bias", {d});
  b.Random("seq.pre.bn_scale", {d}, 0.2f, 1.0f);
  b.Random("seq.pre.bn_shift", {d});
  b.Random("seq.style.table", {n_styles + 1, ds}, 1.0f);
  auto tgca = [&](const std::string& pre) {
    b.Random(pre + ".style.weight", {d, ds});
    b.Random(pre + ".style.bias", {d});
    b.Random(pre + ".norm1.weight", {d}, 0.1f, 1.0f);
    b.Random(pre + ".norm2.weight", {d}, 0.1f, 1.0f);
    for (const char* m : {"w_in", "w_q", "w_k", "w_v", "w_g", "w_o"}) b.Random(pre + "." + m, {d, d});
    b.Random(pre + ".mlp.gate", {2 * d, d});
    b.Random(pre + ".mlp.up", {2 * d, d});
    b.Random(pre + ".mlp.down", {d, 2 * d});
  };
  for (int i = 0; i < o.n_base; ++i) tgca(absl::StrCat("seq.base.", i));
  for (int i = 0; i < o.n_head; ++i) {
    for (int s = 0; s < 3; ++s) {
      const std::string pre = absl::StrCat("seq.pmmm.", i, ".", kStreams[s]);
      b.Random(pre + ".style.weight", {d, ds});
      b.Random(pre + ".style.bias", {d});
      b.Random(pre + ".norm1.weight", {d}, 0.1f, 1.0f);
      b.Random(pre + ".norm2.weight", {d}, 0.1f, 1.0f);
      b.Random(pre + ".mamba.in_proj", {2 * di, d});
      b.Random(pre + ".mamba.conv_w", {di, d_conv}, 0.5f);
      b.Random(pre + ".mamba.conv_b", {di});
      b.Random(pre + ".mamba.x_proj", {r + 2 * d_state, di});
      b.Random(pre + ".mamba.dt_proj.weight", {di, r});
      b.Random(pre + ".mamba.dt_proj.bias", {di}, 1.0f, -2.0f);
      b.Random(pre + ".mamba.A_log", {di, d_state}, 0.5f, 0.5f);
      b.Random(pre + ".mamba.D", {di}, 0.2f, 1.0f);
      b.Random(pre + ".mamba.out_proj", {d, di});
      b.Random(pre + ".mlp.gate", {2 * d, d});
      b.Random(pre + ".mlp.up", {2 * d, d});
      b.Random(pre + ".mlp.down", {d, 2 * d});
    }
  }
  tgca("seq.final");
  b.Random("seq.norm_f.weight", {d}, 0.1f, 1.0f);
  b.Random("seq.head.upper", {k, d}, 1.0f);
  b.Random("seq.head.lower", {k, d}, 1.0f);
  for (int i = 0; i < 2; ++i) {
    const int out = i == 0 ? 45 : 31;
    const std::string pre = i == 0 ? "vq.upper" : "vq.lower";
    b.Random(pre + ".codebook", {k, code_dim}, 1.0f);
    for (size_t c = 0; c < convs[i].size(); ++c) {
      const auto [in_ch, out_ch, ks] = convs[i][c];
      const float scale = 1.0f / std::sqrt(static_cast<float>(in_ch * ks));
      b.Random(absl::StrCat(pre, ".decoder.convs.", c, ".weight"), {out_ch, in_ch, ks}, scale);
      b.Random(absl::StrCat(pre, ".decoder.convs.", c, ".bias"), {out_ch}, 0.1f);
    }
    std::vector<std::pair<int, float>> overrides;
    if (i == 1 && o.yaw_rate_mean != 0.0) overrides.emplace_back(29, static_cast<float>(o.yaw_rate_mean));
    if (i == 1 && o.height_mean != 0.0) overrides.emplace_back(30, static_cast<float>(o.height_mean));
    b.Random(pre + ".pose_mean", {out}, 0.1f, 0.0f, overrides);
    if (i == 1 && o.height_mean != 0.0) {  // and a height that varies by centimetres between codes
      std::vector<float> std_dev(out, 0.05f);
      std_dev[30] = 1.0f;
      w.Add(pre + ".pose_std", {out}, std_dev);
    } else {
      b.Const(pre + ".pose_std", {out}, 0.05f);
    }
  }
  return w;
}

TinyModelOptions DefaultSizeOptions() {
  TinyModelOptions o;
  o.d_model = 128;
  o.n_heads = 4;
  o.n_base = 2;
  o.n_head = 2;
  o.attn_window = 32;
  o.codebook_size = 512;
  o.d_state = 16;
  o.vq_width = 128;
  o.vq_code_dim = 64;
  o.vq_n_res = 2;
  o.scale = 0.1f;
  return o;
}

std::shared_ptr<const Model> LoadTinyModel(const TinyModelOptions& options) {
  absl::StatusOr<WeightsFile> file = WeightsFile::Parse(TinyModelWriter(options).Serialize());
  if (!file.ok()) {
    std::fprintf(stderr, "tiny model: %s\n", std::string(file.status().message()).c_str());
    std::abort();
  }
  absl::StatusOr<std::shared_ptr<const Model>> model = Model::FromWeights(*file);
  if (!model.ok()) {
    std::fprintf(stderr, "tiny model: %s\n", std::string(model.status().message()).c_str());
    std::abort();
  }
  return *model;
}

std::vector<float> TestAudio(double seconds, int sample_rate) { return ClickAudio(seconds, 120.0, sample_rate); }

std::vector<float> ClickAudio(double seconds, double bpm, int sample_rate) {
  const int64_t n = static_cast<int64_t>(seconds * sample_rate);
  std::vector<float> out(n);
  const int64_t beat = static_cast<int64_t>(std::llround(sample_rate * 60.0 / bpm));
  for (int64_t i = 0; i < n; ++i) {
    const double t = static_cast<double>(i) / sample_rate;
    const int64_t since = i % beat;
    const double click = since < sample_rate / 100 ? 0.6 * std::exp(-since * 400.0 / sample_rate) *
                                                         std::sin(2 * M_PI * 1500 * t)
                                                   : 0.0;
    out[i] = static_cast<float>(0.2 * std::sin(2 * M_PI * 110 * t) + click);
  }
  return out;
}

}  // namespace dance::engine::testing
