// Golden parity of the SGMD engine with the PyTorch reference (docs/diffusion.md; fixtures written by
// `python -m training.diffusion.fixtures`): for every tests/golden/<name>/ with an sgmd.json (sgmd-tiny always;
// the shipped model's when its fixtures exist):
//   1. the motion vector, the canonical frame and the vector's inverse,
//   2. the music encoder,
//   3. one denoiser call with the window's music and with music_null,
//   4. DDIM over a window, guided with known values imposed, and unguided without.
// Arrays are row-major (rows, dims), which is the engine's column-major (dims, rows) with the same memory.
// Errors are normalised: max |a - b| / max(1, max |b|).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "engine/diffusion/ddim.h"
#include "engine/diffusion/motion_vector.h"
#include "engine/diffusion/sgmd_model.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "tests/engine/runtime/testing/golden_fixture.h"
#include "tests/engine/runtime/testing/npy.h"

namespace dance::engine {
namespace {

using testing::NpyArray;
using testing::ReadNpy;

constexpr double kSingleCallTolerance = 1e-5;  // one encoder or denoiser call, the motion vector
constexpr double kDdimTolerance = 1e-4;        // S denoiser calls chained through the sampler

using testing::NormalisedError;

double NormalisedError(const Eigen::MatrixXf& mine, const NpyArray& ref) {
  EXPECT_EQ(mine.size(), ref.size());
  if (mine.size() != ref.size()) return INFINITY;
  return NormalisedError(mine.data(), ref.data.data(), ref.size());
}

// An SGMD fixture directory (sgmd.json).
class Golden : public testing::GoldenFixture {
 public:
  explicit Golden(std::filesystem::path dir) : GoldenFixture(std::move(dir), "sgmd.json") {}
  // A (rows, cols) row-major array as the engine's (cols, rows) matrix.
  Eigen::MatrixXf Matrix(const std::string& name) const {
    const NpyArray a = Array(name);
    EXPECT_EQ(a.shape.size(), 2u) << name;
    if (a.shape.size() != 2) return {};
    return Eigen::Map<const Eigen::MatrixXf>(a.data.data(), a.shape[1], a.shape[0]);
  }
};

std::vector<std::filesystem::path> FixtureDirs() { return testing::GoldenDirs("sgmd.json"); }

std::shared_ptr<const SgmdModel> LoadFixtureModel(const Golden& g) {
  absl::StatusOr<std::shared_ptr<const SgmdModel>> m = SgmdModel::Load(g.index()["model"].get<std::string>());
  EXPECT_TRUE(m.ok()) << m.status();
  return m.ok() ? *m : nullptr;
}

// The fixture's style weights as the model's style vector.
Eigen::VectorXf InputStyle(const Golden& g, const SgmdModel& model) {
  const NpyArray style = g.Array("input_style");
  return model.StyleVector(Eigen::Map<const Eigen::VectorXf>(style.data.data(), style.size()));
}

std::vector<JointPositions> Positions(const NpyArray& a) {
  EXPECT_EQ(a.shape.size(), 3u);
  EXPECT_EQ(a.shape.size() == 3 ? a.shape[1] : 0, kNumJoints);
  std::vector<JointPositions> out(a.shape.empty() ? 0 : a.shape[0]);
  for (size_t n = 0; n < out.size(); ++n) {
    for (int j = 0; j < kNumJoints; ++j) {
      out[n][j] = Eigen::Map<const Eigen::Vector3f>(&a.data[(n * kNumJoints + j) * 3]);
    }
  }
  return out;
}

std::vector<float> Flatten(const std::vector<JointPositions>& p) {
  std::vector<float> out;
  for (const JointPositions& frame : p) {
    for (const Eigen::Vector3f& j : frame) out.insert(out.end(), j.data(), j.data() + 3);
  }
  return out;
}

void Report(const Golden& g, const char* what, double err) {
  std::printf("  %s %-26s normalised error %.2e\n", g.name().c_str(), what, err);
}

TEST(SgmdGolden, FixturesExist) { EXPECT_FALSE(FixtureDirs().empty()) << "run from the source root"; }

TEST(SgmdGolden, MotionVectorAndCanonicalFrame) {
  for (const auto& dir : FixtureDirs()) {
    Golden g(dir);
    SCOPED_TRACE(g.name());
    const NpyArray world_ref = g.Array("vector_positions");
    const std::vector<JointPositions> world = Positions(world_ref);
    ASSERT_FALSE(world.empty());

    const Eigen::MatrixXf v = MotionVectors(world);  // (78, T) == (T, 78) row-major
    const double err_vector = NormalisedError(v, g.Array("vector_out"));
    EXPECT_LE(err_vector, kSingleCallTolerance);
    Report(g, "motion vector", err_vector);

    const std::vector<JointPositions> local = ToFrame(world, FrameOf(world[0]));
    const NpyArray canonical = g.Array("canonical_positions");
    ASSERT_EQ(static_cast<int64_t>(Flatten(local).size()), canonical.size());
    const double err_frame = NormalisedError(Flatten(local).data(), canonical.data.data(), canonical.size());
    EXPECT_LE(err_frame, kSingleCallTolerance);
    Report(g, "canonical frame", err_frame);

    // The inverse, of the engine's vectors and of the reference's.
    const Eigen::MatrixXf v_ref = g.Matrix("vector_out");
    std::vector<JointPositions> back, back_ref;
    for (Eigen::Index n = 0; n < v.cols(); ++n) {
      back.push_back(PositionsOfVector(v.col(n)));
      back_ref.push_back(PositionsOfVector(v_ref.col(n)));
    }
    const double err_inverse = NormalisedError(Flatten(back).data(), world_ref.data.data(), world_ref.size());
    const double err_inverse_ref = NormalisedError(Flatten(back_ref).data(), world_ref.data.data(), world_ref.size());
    EXPECT_LE(err_inverse, kSingleCallTolerance);
    EXPECT_LE(err_inverse_ref, kSingleCallTolerance);
    Report(g, "vector inverse", std::max(err_inverse, err_inverse_ref));
  }
}

TEST(SgmdGolden, MusicEncoder) {
  for (const auto& dir : FixtureDirs()) {
    Golden g(dir);
    SCOPED_TRACE(g.name());
    std::shared_ptr<const SgmdModel> model = LoadFixtureModel(g);
    ASSERT_NE(model, nullptr);
    const SgmdModel::Context c = model->EncodeMusic(g.Matrix("input_music"));
    const double err = NormalisedError(c.tokens, g.Array("music_tokens"));
    EXPECT_LE(err, kSingleCallTolerance);
    Report(g, "music encoder", err);
  }
}

TEST(SgmdGolden, DenoiseWithMusicAndWithMusicNull) {
  for (const auto& dir : FixtureDirs()) {
    Golden g(dir);
    SCOPED_TRACE(g.name());
    std::shared_ptr<const SgmdModel> model = LoadFixtureModel(g);
    ASSERT_NE(model, nullptr);
    const Eigen::VectorXf sv = InputStyle(g, *model);
    const Eigen::MatrixXf x_t = g.Matrix("input_x_t");
    const int t = g.index()["t"].get<int>();
    Eigen::MatrixXf x0;
    model->Denoise(x_t, t, model->EncodeMusic(g.Matrix("input_music")), sv, &x0);
    const double err_cond = NormalisedError(x0, g.Array("x0_cond"));
    EXPECT_LE(err_cond, kSingleCallTolerance);
    Report(g, "denoise (music)", err_cond);
    model->Denoise(x_t, t, model->NullContext(), sv, &x0);
    const double err_null = NormalisedError(x0, g.Array("x0_null"));
    EXPECT_LE(err_null, kSingleCallTolerance);
    Report(g, "denoise (music_null)", err_null);
  }
}

TEST(SgmdGolden, DdimWindowGuidedWithKnownValuesAndFree) {
  for (const auto& dir : FixtureDirs()) {
    Golden g(dir);
    SCOPED_TRACE(g.name());
    std::shared_ptr<const SgmdModel> model = LoadFixtureModel(g);
    ASSERT_NE(model, nullptr);
    const Eigen::VectorXf sv = InputStyle(g, *model);
    const SgmdModel::Context c = model->EncodeMusic(g.Matrix("input_music"));
    const SgmdModel::Context none = model->NullContext();
    const Eigen::MatrixXf noise = g.Matrix("ddim_noise");
    WindowKnown known;
    known.values = g.Matrix("ddim_known");
    known.mask = g.Matrix("ddim_mask");
    DdimOptions opt;
    opt.steps = g.index()["ddim_steps"].get<int>();
    opt.guidance = g.index()["ddim_guidance"].get<float>();
    ASSERT_NE(opt.guidance, 1.0f) << "the fixture should exercise guidance";
    int calls = 0;
    const Eigen::MatrixXf x = SampleWindow(*model, c, none, sv, noise, opt, &known, [&](int done, int steps) {
      ++calls;
      EXPECT_EQ(done, calls);
      EXPECT_EQ(steps, opt.steps);
    });
    EXPECT_EQ(calls, opt.steps);
    const double err = NormalisedError(x, g.Array("ddim_out"));
    EXPECT_LE(err, kDdimTolerance);
    Report(g, "ddim (guided, known)", err);
    int known_entries = 0;
    for (Eigen::Index i = 0; i < x.size(); ++i) {
      if (known.mask.data()[i] == 1.0f) {
        ++known_entries;
        ASSERT_EQ(x.data()[i], known.values.data()[i]) << "known entry " << i << " not kept exactly";
      }
    }
    EXPECT_GT(known_entries, 0);

    opt.guidance = 1.0f;
    const Eigen::MatrixXf free = SampleWindow(*model, c, none, sv, noise, opt, nullptr);
    const double err_free = NormalisedError(free, g.Array("ddim_free"));
    EXPECT_LE(err_free, kDdimTolerance);
    Report(g, "ddim (free)", err_free);
    // An empty WindowKnown is the same as none.
    const WindowKnown nothing;
    EXPECT_EQ(SampleWindow(*model, c, none, sv, noise, opt, &nothing), free);
  }
}

}  // namespace
}  // namespace dance::engine
