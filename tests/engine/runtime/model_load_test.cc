// LoadModel / Model::FromWeights: a valid model loads; mismatched ones are refused with clear errors.
#include "engine/runtime/model.h"

#include <cstdio>
#include <fstream>

#include "absl/strings/match.h"
#include "gtest/gtest.h"
#include "tests/engine/runtime/testing/tiny_model.h"

namespace dance::engine {
namespace {

using testing::TinyModelWriter;

absl::Status LoadFrom(const WeightsWriter& w) {
  absl::StatusOr<WeightsFile> f = WeightsFile::Parse(w.Serialize());
  if (!f.ok()) return f.status();
  return Model::FromWeights(*f).status();
}

TEST(ModelLoad, TinyModelLoadsFromDisk) {
  const std::string path = ::testing::TempDir() + "/tiny.dncw";
  ASSERT_TRUE(TinyModelWriter({}).WriteFile(path).ok());
  absl::StatusOr<std::shared_ptr<const Model>> m = LoadModel(path);
  ASSERT_TRUE(m.ok()) << m.status();
  EXPECT_EQ((*m)->model_id(), "cpp-tiny-1");
  EXPECT_EQ((*m)->styles().size(), 2u);
  EXPECT_EQ(*(*m)->StyleIndex("tango"), 1);
  EXPECT_EQ(*(*m)->StyleIndex("none"), 2);
  EXPECT_FALSE((*m)->StyleIndex("polka").ok());
  EXPECT_DOUBLE_EQ((*m)->LatencyMs(), 0.0);
}

TEST(ModelLoad, TruncatedFileOnDiskIsRefused) {
  const std::string path = ::testing::TempDir() + "/trunc.dncw";
  std::vector<uint8_t> bytes = TinyModelWriter({}).Serialize();
  bytes.resize(bytes.size() * 2 / 3);
  std::ofstream(path, std::ios::binary).write(reinterpret_cast<const char*>(bytes.data()), bytes.size());
  absl::Status s = LoadModel(path).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss) << s;
  EXPECT_TRUE(absl::StrContains(s.message(), path)) << s;
}

TEST(ModelLoad, WrongShapeNamesTheTensor) {
  WeightsWriter w = TinyModelWriter({});
  w.Remove("seq.base.0.w_q");
  w.Add("seq.base.0.w_q", {16, 15}, std::vector<float>(16 * 15, 0.1f));
  absl::Status s = LoadFrom(w);
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_TRUE(absl::StrContains(s.message(), "seq.base.0.w_q")) << s;
  EXPECT_TRUE(absl::StrContains(s.message(), "[16, 15]")) << s;
}

TEST(ModelLoad, MissingTensorIsNamed) {
  WeightsWriter w = TinyModelWriter({});
  w.Remove("seq.pmmm.0.lower.mamba.A_log");
  absl::Status s = LoadFrom(w);
  EXPECT_EQ(s.code(), absl::StatusCode::kNotFound);
  EXPECT_TRUE(absl::StrContains(s.message(), "seq.pmmm.0.lower.mamba.A_log")) << s;
}

TEST(ModelLoad, HyperparametersMustMatchTheFrontEnd) {
  WeightsWriter w = TinyModelWriter({});
  w.metadata()["hyperparameters"]["feature_dim"] = 100;
  absl::Status s = LoadFrom(w);
  EXPECT_FALSE(s.ok());
}

TEST(ModelLoad, UnknownDecoderOpIsRefused) {
  WeightsWriter w = TinyModelWriter({});
  w.metadata()["vq"]["lower"]["decoder_ops"][2] = {{"op", "gelu"}};
  absl::Status s = LoadFrom(w);
  EXPECT_TRUE(absl::StrContains(s.message(), "gelu")) << s;
}

TEST(ModelLoad, StyleCountMustMatch) {
  WeightsWriter w = TinyModelWriter({});
  w.metadata()["styles"] = {"waltz"};
  EXPECT_FALSE(LoadFrom(w).ok());
}

}  // namespace
}  // namespace dance::engine
