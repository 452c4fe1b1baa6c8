// Golden parity with the PyTorch reference (tests/golden/README.md): for every fixture directory
// tests/golden/<name>/ (test-tiny always; default when the trained model's fixtures exist):
//   1. teacher-forced trace: every layer's activations at each of S steps,
//   2. greedy generation for N = 256 steps: identical codes, logits within tolerance,
//   3. streaming VQ decoding of the greedy codes, root integration and bone projection.
// Errors are normalised: max |a - b| / max(1, max |b|).
#include <filesystem>
#include <fstream>

#include "absl/strings/str_cat.h"
#include "engine/model/sequence_model.h"
#include "engine/nn/sampling.h"
#include "engine/runtime/model.h"
#include "engine/vq/pose_reconstructor.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "tests/engine/runtime/testing/golden_fixture.h"
#include "tests/engine/runtime/testing/npy.h"

namespace dance::engine {
namespace {

using testing::NpyArray;
using testing::ReadNpy;

constexpr double kLayerTolerance = 1e-6;   // the target for every layer and the logits
// Except the final RMSNorm's output: it rescales the residual stream (whose float32 error is inside 1e-6)
// by weight / rms, up to ~2.6x for default-20261202-5 (norm_f 1.16e-6, its input 7.7e-7, the logits after
// it 6.6e-7). Computing the scan's state sum in double did not move it (pmmm1 8.0e-7 -> 7.5e-7, norm_f
// unchanged), so the float32 error comes from further up; the logits keep the 1e-6 target.
constexpr double kFinalNormTolerance = 2e-6;
// Greedy logits after up to 256 steps of carried KV cache and Mamba state: float32 rounding of two
// different summation orders accumulates to a few 1e-6.
constexpr double kGreedyLogitTolerance = 1e-5;
constexpr double kDecodeTolerance = 1e-5;  // the VQ decoder runs ~20 convs deep
constexpr double kPositionTolerance = 1e-4;  // metres; the reference integrates in float64

using testing::NormalisedError;

// A token-model fixture directory (index.json).
class Golden : public testing::GoldenFixture {
 public:
  explicit Golden(std::filesystem::path dir) : GoldenFixture(std::move(dir), "index.json") {}
};

std::vector<std::filesystem::path> FixtureDirs() { return testing::GoldenDirs("index.json"); }

std::shared_ptr<const Model> LoadFixtureModel(const Golden& g) {
  absl::StatusOr<std::shared_ptr<const Model>> m = LoadModel(g.index()["model"].get<std::string>());
  EXPECT_TRUE(m.ok()) << m.status();
  return m.ok() ? *m : nullptr;
}

Eigen::VectorXf FixtureStyle(const Golden& g, const SequenceModel& seq) {
  const NpyArray w = g.Array("input_style");
  std::vector<std::pair<int, float>> rows;
  for (int i = 0; i < w.size(); ++i) {
    if (w.data[i] != 0.0f) rows.emplace_back(i, w.data[i]);
  }
  return seq.StyleVector(rows);
}

TEST(Golden, FixturesExist) { EXPECT_FALSE(FixtureDirs().empty()) << "run from the source root"; }

TEST(Golden, TeacherForcedTraceMatchesEveryLayer) {
  for (const auto& dir : FixtureDirs()) {
    Golden g(dir);
    SCOPED_TRACE(g.name());
    std::shared_ptr<const Model> model = LoadFixtureModel(g);
    ASSERT_NE(model, nullptr);
    const SequenceModel& seq = model->sequence();
    const SeqConfig& c = seq.config();
    ASSERT_EQ(c.music_lookahead_steps, 0);
    const NpyArray features = g.Array("input_features"), pre = g.Array("input_pre");
    const NpyArray codes_u = g.Array("trace_codes_upper"), codes_l = g.Array("trace_codes_lower");
    const int steps = g.index()["trace_steps"].get<int>();
    SequenceState state = seq.NewState();
    seq.SetStyle(FixtureStyle(g, seq), &state);
    Workspace ws;
    std::map<std::string, double> worst;
    for (int t = 0; t < steps; ++t) {
      LaneInput in{features.data.data() + 4 * t * c.feature_dim, pre.data.data() + (4 * t + 3) * c.pre_dim,
                   static_cast<int>(codes_u.data[t]), static_cast<int>(codes_l.data[t]), &state};
      Trace trace;
      seq.Step({&in, 1}, ws, &trace);
      for (const auto& layer : g.index()["trace_layers"]) {
        const std::string name = layer.get<std::string>();
        if (name.rfind("logits", 0) == 0) continue;  // compared below from the workspace
        ASSERT_TRUE(trace.count(name)) << "engine has no trace point '" << name << "'";
        const NpyArray ref = g.Array("trace_" + name);  // (S, 3, d)
        const Eigen::MatrixXf& mine = trace[name];       // (d, 3): column-major == (3, d) row-major
        const int64_t n = 3 * c.d_model;
        ASSERT_EQ(ref.size(), steps * n) << name;
        worst[name] = std::max(worst[name], NormalisedError(mine.data(), ref.data.data() + t * n, n));
      }
      const NpyArray lu = g.Array("trace_logits_upper"), ll = g.Array("trace_logits_lower");
      const int k = c.codebook_size;
      worst["logits_upper"] = std::max(worst["logits_upper"],
                                       NormalisedError(ws.logits_u.col(0).data(), lu.data.data() + t * k, k));
      worst["logits_lower"] = std::max(worst["logits_lower"],
                                       NormalisedError(ws.logits_l.col(0).data(), ll.data.data() + t * k, k));
    }
    for (const auto& [name, err] : worst) {
      EXPECT_LE(err, name == "norm_f" ? kFinalNormTolerance : kLayerTolerance) << name;
      std::printf("  %s %-18s normalised error %.2e\n", g.name().c_str(), name.c_str(), err);
    }
  }
}

// Greedy codes for all N steps, then the decoded features and positions of those codes.
TEST(Golden, GreedyCodesDecodingAndPositions) {
  for (const auto& dir : FixtureDirs()) {
    Golden g(dir);
    SCOPED_TRACE(g.name());
    std::shared_ptr<const Model> model = LoadFixtureModel(g);
    ASSERT_NE(model, nullptr);
    const SequenceModel& seq = model->sequence();
    const SeqConfig& c = seq.config();
    const int k = c.codebook_size;
    const NpyArray features = g.Array("input_features"), pre = g.Array("input_pre");
    const NpyArray ref_u = g.Array("greedy_codes_upper"), ref_l = g.Array("greedy_codes_lower");
    const NpyArray ref_lu = g.Array("greedy_logits_upper"), ref_ll = g.Array("greedy_logits_lower");
    const int steps = g.index()["steps"].get<int>();
    ASSERT_GE(steps, 256);
    SequenceState state = seq.NewState();
    seq.SetStyle(FixtureStyle(g, seq), &state);
    Workspace ws;
    std::mt19937_64 gen(0);
    SamplerScratch scratch(k);
    SamplingOptions greedy;
    greedy.temperature = 0.0f;
    int u = k, l = k, mismatches = 0;
    double worst_logits = 0.0;
    std::vector<int> codes_u, codes_l;
    for (int t = 0; t < steps; ++t) {
      LaneInput in{features.data.data() + 4 * t * c.feature_dim, pre.data.data() + (4 * t + 3) * c.pre_dim, u, l,
                   &state};
      seq.Step({&in, 1}, ws);
      worst_logits = std::max(worst_logits, NormalisedError(ws.logits_u.col(0).data(), ref_lu.data.data() + t * k, k));
      worst_logits = std::max(worst_logits, NormalisedError(ws.logits_l.col(0).data(), ref_ll.data.data() + t * k, k));
      u = SampleCode(absl::MakeConstSpan(ws.logits_u.col(0).data(), k), greedy, gen, scratch);
      l = SampleCode(absl::MakeConstSpan(ws.logits_l.col(0).data(), k), greedy, gen, scratch);
      mismatches += (u != static_cast<int>(ref_u.data[t])) + (l != static_cast<int>(ref_l.data[t]));
      // Keep following the reference's codes so one near-tie cannot derail the rest of the comparison.
      u = static_cast<int>(ref_u.data[t]);
      l = static_cast<int>(ref_l.data[t]);
      codes_u.push_back(u);
      codes_l.push_back(l);
    }
    EXPECT_EQ(mismatches, 0) << "greedy codes differ (min reference margin "
                             << g.index()["greedy_min_margin"] << ")";
    EXPECT_LE(worst_logits, kGreedyLogitTolerance);
    std::printf("  %s greedy: %d steps, %d code mismatches, logits normalised error %.2e\n", g.name().c_str(),
                steps, mismatches, worst_logits);

    // 3. Streaming decode of the greedy codes, then root integration and bone projection.
    const NpyArray dec_u = g.Array("decoded_upper"), dec_l = g.Array("decoded_lower");
    const NpyArray pos_ref = g.Array("positions");
    VqDecoderState su = model->upper_decoder().NewState(), sl = model->lower_decoder().NewState();
    VqDecoderScratch xu = model->upper_decoder().NewScratch(), xl = model->lower_decoder().NewScratch();
    PoseReconstructor rec(model->skeleton());
    PoseState pose;
    double worst_u = 0.0, worst_l = 0.0, worst_pos = 0.0;
    for (int t = 0; t < steps; ++t) {
      const Eigen::MatrixXf fu = model->upper_decoder().Decode(codes_u[t], su, xu);  // (45, 4)
      const Eigen::MatrixXf fl = model->lower_decoder().Decode(codes_l[t], sl, xl);  // (31, 4)
      for (int f = 0; f < 4; ++f) {
        const int64_t row = 4 * t + f;
        worst_u = std::max(worst_u, NormalisedError(fu.col(f).data(), dec_u.data.data() + row * 45, 45));
        worst_l = std::max(worst_l, NormalisedError(fl.col(f).data(), dec_l.data.data() + row * 31, 31));
        std::array<Eigen::Vector3f, kNumJoints> p;
        std::array<Eigen::Quaternionf, kNumJoints> q;
        rec.Reconstruct(fu.col(f).data(), fl.col(f).data(), pose, &p, &q);
        for (int j = 0; j < kNumJoints; ++j) {
          const float* r = pos_ref.data.data() + (row * kNumJoints + j) * 3;
          worst_pos = std::max(worst_pos, static_cast<double>((p[j] - Eigen::Vector3f(r[0], r[1], r[2])).norm()));
        }
      }
    }
    EXPECT_LE(worst_u, kDecodeTolerance);
    EXPECT_LE(worst_l, kDecodeTolerance);
    EXPECT_LE(worst_pos, kPositionTolerance);
    std::printf("  %s decode: upper %.2e lower %.2e normalised; positions max %.2e m over %d frames\n",
                g.name().c_str(), worst_u, worst_l, worst_pos, 4 * steps);
  }
}

}  // namespace
}  // namespace dance::engine
