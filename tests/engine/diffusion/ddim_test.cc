// The DDIM sampler's schedule, noise and constraints (docs/diffusion.md section 4), on models/sgmd-tiny.dncw.
#include "engine/diffusion/ddim.h"

#include <cmath>
#include <random>
#include <vector>

#include "gtest/gtest.h"

namespace dance::engine {
namespace {

std::shared_ptr<const SgmdModel> TinyModel() {
  static std::shared_ptr<const SgmdModel> model = [] {
    absl::StatusOr<std::shared_ptr<const SgmdModel>> m = SgmdModel::Load("models/sgmd-tiny.dncw");
    EXPECT_TRUE(m.ok()) << m.status() << " (run from the source root)";
    return m.ok() ? *m : nullptr;
  }();
  return model;
}

Eigen::MatrixXf Noise(const SgmdModel& m, uint64_t seed) {
  std::mt19937_64 gen(seed);
  Eigen::MatrixXf e(m.config().pose_dim, m.config().frames);
  FillStandardNormal(gen, &e);
  return e;
}

TEST(DdimTimesteps, MatchPythonsRoundHalfToEven) {
  // Python: training.diffusion.sample.ddim_timesteps.
  EXPECT_EQ(DdimTimesteps(1000, 5), (std::vector<int>{999, 749, 500, 250, 0}));  // 499.5 -> 500
  EXPECT_EQ(DdimTimesteps(1000, 1), (std::vector<int>{999}));
  EXPECT_EQ(DdimTimesteps(6, 3), (std::vector<int>{5, 2, 0}));  // 2.5 -> 2, not 3
  EXPECT_EQ(DdimTimesteps(1000, 9), (std::vector<int>{999, 874, 749, 624, 500, 375, 250, 125, 0}));
  EXPECT_EQ(DdimTimesteps(10, 4), (std::vector<int>{9, 6, 3, 0}));
  const std::vector<int> fifty = DdimTimesteps(1000, 50);
  ASSERT_EQ(fifty.size(), 50u);
  EXPECT_EQ(std::vector<int>(fifty.begin(), fifty.begin() + 6), (std::vector<int>{999, 979, 958, 938, 917, 897}));
  EXPECT_EQ(std::vector<int>(fifty.end() - 3, fifty.end()), (std::vector<int>{41, 20, 0}));
  const std::vector<int> all = DdimTimesteps(1000, 1000);
  for (int i = 0; i < 1000; ++i) ASSERT_EQ(all[i], 999 - i);
}

TEST(DdimTimesteps, StepsAreClampedToOneThroughT) {
  EXPECT_EQ(DdimTimesteps(1000, 0), (std::vector<int>{999}));
  EXPECT_EQ(DdimTimesteps(4, 9), (std::vector<int>{3, 2, 1, 0}));
}

TEST(FillStandardNormal, FollowsTheContractFormulaInStorageOrder) {
  std::mt19937_64 gen(42), ref(42);
  Eigen::MatrixXf e(3, 4);
  FillStandardNormal(gen, &e);
  for (Eigen::Index i = 0; i < e.size(); ++i) {
    const double u1 = static_cast<double>(ref() >> 11) * std::ldexp(1.0, -53);
    const double u2 = static_cast<double>(ref() >> 11) * std::ldexp(1.0, -53);
    const float want = static_cast<float>(std::sqrt(-2.0 * std::log(1.0 - u1)) * std::cos(2.0 * M_PI * u2));
    EXPECT_FLOAT_EQ(e.data()[i], want) << i;  // column-major: e(0, 0), e(1, 0), e(2, 0), e(0, 1), ...
  }
  EXPECT_EQ(gen(), ref()) << "two draws per value";
}

TEST(FillStandardNormal, SameSeedSameValuesAndStandardMoments) {
  std::mt19937_64 a(7), b(7), c(8);
  Eigen::MatrixXf x(100, 1000), y(100, 1000), z(100, 1000);
  FillStandardNormal(a, &x);
  FillStandardNormal(b, &y);
  FillStandardNormal(c, &z);
  EXPECT_EQ(x, y);
  EXPECT_NE(x, z);
  const double mean = x.cast<double>().mean();
  const double var = (x.cast<double>().array() - mean).square().mean();
  EXPECT_NEAR(mean, 0.0, 0.02);  // 100k values: the mean's std is 0.003
  EXPECT_NEAR(var, 1.0, 0.03);   // the variance's std is 0.0045
  EXPECT_TRUE(x.allFinite());
  EXPECT_NEAR((x.array().abs() < 1.0f).cast<double>().mean(), 0.6827, 0.01);
}

TEST(SampleWindow, OneStepIsOneDenoiseOfTheImposedNoise) {
  std::shared_ptr<const SgmdModel> m = TinyModel();
  ASSERT_NE(m, nullptr);
  const SgmdConfig& c = m->config();
  const Eigen::MatrixXf e = Noise(*m, 1);
  WindowKnown known;
  known.values = Noise(*m, 2);
  known.mask = Eigen::MatrixXf::Zero(c.pose_dim, c.frames);
  known.mask.col(0).setOnes();
  known.mask.row(1).setOnes();
  const Eigen::VectorXf sv = m->StyleVector(Eigen::VectorXf::Unit(c.n_styles + 1, c.n_styles));
  const SgmdModel::Context music = m->NullContext();
  DdimOptions opt;
  opt.steps = 1;
  const Eigen::MatrixXf x = SampleWindow(*m, music, SgmdModel::Context(), sv, e, opt, &known);

  const int t = c.diffusion_steps - 1;
  const double abar = m->alphas_cumprod()[t];
  const Eigen::ArrayXXf mask = known.mask.array();
  const Eigen::MatrixXf x_t = mask * (static_cast<float>(std::sqrt(abar)) * known.values.array() +
                                      static_cast<float>(std::sqrt(1.0 - abar)) * e.array()) +
                              (1.0f - mask) * e.array();
  Eigen::MatrixXf x0;
  m->Denoise(x_t, t, music, sv, &x0);
  const Eigen::MatrixXf want = (mask * known.values.array() + (1.0f - mask) * x0.array()).matrix();
  EXPECT_EQ(x, want);
}

TEST(SampleWindow, DeterministicKnownValuesExactAndProgressReported) {
  std::shared_ptr<const SgmdModel> m = TinyModel();
  ASSERT_NE(m, nullptr);
  const SgmdConfig& c = m->config();
  const Eigen::MatrixXf e = Noise(*m, 3);
  std::mt19937 gen(4);
  std::bernoulli_distribution coin(0.3);
  WindowKnown known;
  known.values = Noise(*m, 5);
  known.mask.resize(c.pose_dim, c.frames);
  for (Eigen::Index i = 0; i < known.mask.size(); ++i) known.mask.data()[i] = coin(gen) ? 1.0f : 0.0f;
  Eigen::VectorXf w = Eigen::VectorXf::Zero(c.n_styles + 1);
  w(0) = 0.5f;
  w(2) = 0.5f;
  const Eigen::VectorXf sv = m->StyleVector(w);
  const SgmdModel::Context none = m->NullContext();
  Eigen::MatrixXf music = Eigen::MatrixXf::Random(c.music_dim(), c.tokens());
  const SgmdModel::Context ctx = m->EncodeMusic(music);
  DdimOptions opt;
  opt.steps = 7;
  opt.guidance = 2.5f;
  std::vector<int> done;
  const Eigen::MatrixXf x = SampleWindow(*m, ctx, none, sv, e, opt, &known, [&](int i, int steps) {
    EXPECT_EQ(steps, 7);
    done.push_back(i);
  });
  EXPECT_EQ(done, (std::vector<int>{1, 2, 3, 4, 5, 6, 7}));
  EXPECT_EQ(SampleWindow(*m, ctx, none, sv, e, opt, &known), x);
  ASSERT_TRUE(x.allFinite());
  for (Eigen::Index i = 0; i < x.size(); ++i) {
    if (known.mask.data()[i] == 1.0f) {
      ASSERT_EQ(x.data()[i], known.values.data()[i]) << i;
    }
  }
  // The guidance and the music matter.
  opt.guidance = 1.0f;
  EXPECT_FALSE(SampleWindow(*m, ctx, none, sv, e, opt, &known).isApprox(x, 1e-3f));
  EXPECT_FALSE(SampleWindow(*m, none, none, sv, e, opt, &known).isApprox(SampleWindow(*m, ctx, none, sv, e, opt,
                                                                                       &known), 1e-3f));
}

}  // namespace
}  // namespace dance::engine
