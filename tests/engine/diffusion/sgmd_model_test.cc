// SgmdModel::Load: the tiny SGMD file loads with its metadata; other and damaged files are refused with a
// Status naming the problem. Plus the small pure parts of the model's API.
#include "engine/diffusion/sgmd_model.h"

#include <cmath>
#include <string>

#include "absl/strings/match.h"
#include "engine/nn/weights_file.h"
#include "engine/nn/weights_writer.h"
#include "gtest/gtest.h"

namespace dance::engine {
namespace {

constexpr char kTiny[] = "models/sgmd-tiny.dncw";

// models/sgmd-tiny.dncw rewritten through `edit` (which may change the metadata and drop or replace tensors).
template <typename Edit>
absl::Status LoadEdited(const std::string& name, Edit edit) {
  absl::StatusOr<WeightsFile> f = WeightsFile::Load(kTiny);
  EXPECT_TRUE(f.ok()) << f.status();
  if (!f.ok()) return f.status();
  WeightsWriter w(f->metadata());
  for (const auto& [tensor_name, t] : f->tensors()) w.Add(tensor_name, t.shape, t.data);
  edit(w);
  const std::string path = ::testing::TempDir() + "/" + name + ".dncw";
  EXPECT_TRUE(w.WriteFile(path).ok());
  return SgmdModel::Load(path).status();
}

// The same, returning the model.
template <typename Edit>
std::shared_ptr<const SgmdModel> LoadEditedModel(const std::string& name, Edit edit) {
  absl::StatusOr<WeightsFile> f = WeightsFile::Load(kTiny);
  EXPECT_TRUE(f.ok()) << f.status();
  if (!f.ok()) return nullptr;
  WeightsWriter w(f->metadata());
  for (const auto& [tensor_name, t] : f->tensors()) w.Add(tensor_name, t.shape, t.data);
  edit(w);
  const std::string path = ::testing::TempDir() + "/" + name + ".dncw";
  EXPECT_TRUE(w.WriteFile(path).ok());
  absl::StatusOr<std::shared_ptr<const SgmdModel>> m = SgmdModel::Load(path);
  EXPECT_TRUE(m.ok()) << m.status();
  return m.ok() ? *m : nullptr;
}

TEST(SgmdModelLoad, TinyModelAndItsMetadata) {
  absl::StatusOr<std::shared_ptr<const SgmdModel>> m = SgmdModel::Load(kTiny);
  ASSERT_TRUE(m.ok()) << m.status() << " (run from the source root)";
  const SgmdModel& model = **m;
  const SgmdConfig& c = model.config();
  EXPECT_EQ(model.model_id(), "sgmd-tiny");
  EXPECT_EQ(c.d_model, 32);
  EXPECT_EQ(c.n_heads, 2);
  EXPECT_EQ(c.n_layers, 2);
  EXPECT_EQ(c.n_music_layers, 1);
  EXPECT_EQ(c.frames, 8);
  EXPECT_EQ(c.tokens(), 4);
  EXPECT_EQ(c.music_dim(), 472);
  EXPECT_EQ(c.pose_dim, 78);
  EXPECT_NEAR(c.style_mod_r, 1.0 / std::sqrt(32.0), 1e-7);
  EXPECT_EQ(model.styles().size(), 6u);
  EXPECT_EQ(model.styles()[3], "waltz");
  EXPECT_EQ(model.sampling_defaults().steps, 50);
  EXPECT_EQ(model.sampling_defaults().guidance, 1.0f);
  EXPECT_EQ(model.sampling_defaults().overlap_frames, 4);
  ASSERT_EQ(model.alphas_cumprod().size(), 1000u);
  for (size_t t = 1; t < 1000; ++t) ASSERT_LT(model.alphas_cumprod()[t], model.alphas_cumprod()[t - 1]) << t;
  EXPECT_EQ(model.pose_std().size(), 78);
  EXPECT_EQ(model.music_mean().size(), 108);
  EXPECT_EQ(model.skeleton().parents[7], 4);
  EXPECT_EQ(c.prediction, SgmdConfig::Prediction::kV);
}

TEST(SgmdModelLoad, TokenModelIsNotAnSgmdModel) {
  absl::Status s = SgmdModel::Load("models/test-tiny.dncw").status();
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << s;
  EXPECT_TRUE(absl::StrContains(s.message(), "sgmd")) << s;
}

TEST(SgmdModelLoad, MissingFileIsNotFound) {
  absl::Status s = SgmdModel::Load("models/no-such-model.dncw").status();
  EXPECT_EQ(s.code(), absl::StatusCode::kNotFound) << s;
}

TEST(SgmdModelLoad, MissingOrMisshapedTensorIsNamed) {
  absl::Status s = LoadEdited("missing", [](WeightsWriter& w) { w.Remove("sgmd.blocks.1.cross_attn.v.bias"); });
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << s;
  EXPECT_TRUE(absl::StrContains(s.message(), "sgmd.blocks.1.cross_attn.v.bias")) << s;
  s = LoadEdited("misshaped", [](WeightsWriter& w) {
    w.Remove("sgmd.music_null");
    w.Add("sgmd.music_null", {5, 32}, std::vector<float>(5 * 32, 0.0f));
  });
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << s;
  EXPECT_TRUE(absl::StrContains(s.message(), "sgmd.music_null")) << s;
  s = LoadEdited("schedule", [](WeightsWriter& w) {
    w.Remove("sgmd.alphas_cumprod");
    w.Add("sgmd.alphas_cumprod", {1000}, std::vector<float>(1000, 1.0f));
  });
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << s;
  EXPECT_TRUE(absl::StrContains(s.message(), "alphas_cumprod")) << s;
}

TEST(SgmdModelLoad, BadMetadataIsNamed) {
  absl::Status s = LoadEdited("kind", [](WeightsWriter& w) { w.metadata()["kind"] = "tokens"; });
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << s;
  EXPECT_TRUE(absl::StrContains(s.message(), "sgmd")) << s;
  s = LoadEdited("pose_dim", [](WeightsWriter& w) { w.metadata()["sgmd"]["pose_dim"] = 77; });
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << s;
  EXPECT_TRUE(absl::StrContains(s.message(), "pose_dim")) << s;
  s = LoadEdited("frames", [](WeightsWriter& w) { w.metadata()["sgmd"]["frames"] = 9; });
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << s;
  EXPECT_TRUE(absl::StrContains(s.message(), "frames_per_token")) << s;
  s = LoadEdited("no_config", [](WeightsWriter& w) { w.metadata().erase("sgmd"); });
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << s;
  s = LoadEdited("styles", [](WeightsWriter& w) { w.metadata()["styles"].erase(0); });
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << s;
  EXPECT_TRUE(absl::StrContains(s.message(), "styles")) << s;
  s = LoadEdited("prediction", [](WeightsWriter& w) { w.metadata()["sgmd"]["prediction"] = "eps"; });
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << s;
  EXPECT_TRUE(absl::StrContains(s.message(), "sgmd.prediction")) << s;
  s = LoadEdited("steps", [](WeightsWriter& w) { w.metadata()["sampling"]["steps"] = 0; });
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << s;
  EXPECT_TRUE(absl::StrContains(s.message(), "sampling.steps")) << s;
}

// The same weights read as an x0 model (the layer's output as it is, the default for files without
// sgmd.prediction) and as a v model: x0 = sqrt(abar) x_t - sqrt(1 - abar) out. The v path is checked
// against PyTorch by the golden test; this ties the x0 path to it.
TEST(SgmdModel, VPredictionIsTheOutputLayerReadThroughTheSchedule) {
  std::shared_ptr<const SgmdModel> v = LoadEditedModel("as_v", [](WeightsWriter&) {});
  std::shared_ptr<const SgmdModel> x0 =
      LoadEditedModel("as_x0", [](WeightsWriter& w) { w.metadata()["sgmd"].erase("prediction"); });
  ASSERT_NE(v, nullptr);
  ASSERT_NE(x0, nullptr);
  EXPECT_EQ(x0->config().prediction, SgmdConfig::Prediction::kX0);
  const SgmdConfig& c = v->config();
  const Eigen::MatrixXf x_t = Eigen::MatrixXf::Random(c.pose_dim, c.frames);
  const Eigen::VectorXf sv = v->StyleVector(Eigen::VectorXf::Unit(c.n_styles + 1, 2));
  const Eigen::MatrixXf music = Eigen::MatrixXf::Random(c.music_dim(), c.tokens());
  for (int t : {0, 250, 999}) {
    Eigen::MatrixXf from_v, out;
    v->Denoise(x_t, t, v->EncodeMusic(music), sv, &from_v);
    x0->Denoise(x_t, t, x0->EncodeMusic(music), sv, &out);
    const float abar = static_cast<float>(v->alphas_cumprod()[t]);
    const Eigen::MatrixXf want = std::sqrt(abar) * x_t - std::sqrt(1.0f - abar) * out;
    EXPECT_LE((from_v - want).cwiseAbs().maxCoeff(), 1e-5f) << "t " << t;
    EXPECT_GT((from_v - out).cwiseAbs().maxCoeff(), 1e-2f) << "t " << t;  // the two readings differ
  }
}

TEST(SgmdModel, StyleVectorMixesTableRows) {
  absl::StatusOr<std::shared_ptr<const SgmdModel>> m = SgmdModel::Load(kTiny);
  ASSERT_TRUE(m.ok()) << m.status();
  const int s = (*m)->config().n_styles;
  const Eigen::VectorXf a = (*m)->StyleVector(Eigen::VectorXf::Unit(s + 1, 1));
  const Eigen::VectorXf none = (*m)->StyleVector(Eigen::VectorXf::Unit(s + 1, s));
  ASSERT_EQ(a.size(), (*m)->config().style_dim);
  Eigen::VectorXf w = Eigen::VectorXf::Zero(s + 1);
  w(1) = 0.25f;
  w(s) = 0.75f;
  EXPECT_TRUE((*m)->StyleVector(w).isApprox(0.25f * a + 0.75f * none, 1e-6f));
}

TEST(SgmdModel, ContextsHoldEveryBlocksKeysAndValues) {
  absl::StatusOr<std::shared_ptr<const SgmdModel>> m = SgmdModel::Load(kTiny);
  ASSERT_TRUE(m.ok()) << m.status();
  const SgmdConfig& c = (*m)->config();
  const SgmdModel::Context none = (*m)->NullContext();
  const SgmdModel::Context music = (*m)->EncodeMusic(Eigen::MatrixXf::Random(c.music_dim(), c.tokens()));
  for (const SgmdModel::Context* ctx : {&none, &music}) {
    EXPECT_EQ(ctx->tokens.rows(), c.d_model);
    EXPECT_EQ(ctx->tokens.cols(), c.tokens());
    EXPECT_EQ(ctx->pooled.size(), c.d_model);
    ASSERT_EQ(ctx->keys.size(), static_cast<size_t>(c.n_layers));
    ASSERT_EQ(ctx->values.size(), static_cast<size_t>(c.n_layers));
    EXPECT_EQ(ctx->keys[0].rows(), c.d_model);
    EXPECT_EQ(ctx->values[1].cols(), c.tokens());
  }
  EXPECT_FALSE(none.tokens.isApprox(music.tokens, 1e-3f));
  // Denoise sizes its output and reads nothing of it.
  const Eigen::MatrixXf x_t = Eigen::MatrixXf::Random(c.pose_dim, c.frames);
  const Eigen::VectorXf sv = (*m)->StyleVector(Eigen::VectorXf::Unit(c.n_styles + 1, 0));
  Eigen::MatrixXf a, b = Eigen::MatrixXf::Constant(3, 3, 1e9f);
  (*m)->Denoise(x_t, 10, music, sv, &a);
  (*m)->Denoise(x_t, 10, music, sv, &b);
  EXPECT_EQ(a.rows(), c.pose_dim);
  EXPECT_EQ(a.cols(), c.frames);
  EXPECT_EQ(a, b);
  (*m)->Denoise(x_t, 900, music, sv, &b);
  EXPECT_FALSE(a.isApprox(b, 1e-3f)) << "the step must matter";
}

}  // namespace
}  // namespace dance::engine
