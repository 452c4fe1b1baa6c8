// The streaming VQ decoder: op-list validation, causality and state handling on the C++ tiny model.
#include "engine/vq/vq_decoder.h"

#include "absl/strings/match.h"
#include "gtest/gtest.h"
#include "tests/engine/runtime/testing/tiny_model.h"

namespace dance::engine {
namespace {

WeightsFile TinyWeights() {
  absl::StatusOr<WeightsFile> f = WeightsFile::Parse(testing::TinyModelWriter({}).Serialize());
  EXPECT_TRUE(f.ok());
  return *std::move(f);
}

TEST(VqDecoder, DecodesFourFramesPerCode) {
  WeightsFile w = TinyWeights();
  absl::StatusOr<VqDecoder> dec = VqDecoder::Load(w, "upper");
  ASSERT_TRUE(dec.ok()) << dec.status();
  EXPECT_EQ(dec->out_dim(), 45);
  EXPECT_EQ(dec->frames_per_code(), 4);
  VqDecoderState st = dec->NewState();
  VqDecoderScratch sc = dec->NewScratch();
  const Eigen::MatrixXf& y = dec->Decode(3, st, sc);
  EXPECT_EQ(y.rows(), 45);
  EXPECT_EQ(y.cols(), 4);
  EXPECT_TRUE(y.allFinite());
}

// The output for a code depends on the codes before it (conv history) and is reproducible from a copy
// of the state.
TEST(VqDecoder, StateCarriesHistoryAndCopiesExactly) {
  WeightsFile w = TinyWeights();
  absl::StatusOr<VqDecoder> dec = VqDecoder::Load(w, "lower");
  ASSERT_TRUE(dec.ok());
  VqDecoderScratch sc = dec->NewScratch();
  VqDecoderState a = dec->NewState(), b = dec->NewState();
  dec->Decode(1, a, sc);
  dec->Decode(2, b, sc);
  VqDecoderState a_copy = a;
  const Eigen::MatrixXf ya = dec->Decode(5, a, sc);
  const Eigen::MatrixXf yb = dec->Decode(5, b, sc);
  EXPECT_GT((ya - yb).norm(), 1e-6f);
  EXPECT_EQ(ya, dec->Decode(5, a_copy, sc));
}

TEST(VqDecoder, BatchEqualsOneLaneAtATime) {
  WeightsFile w = TinyWeights();
  absl::StatusOr<VqDecoder> dec = VqDecoder::Load(w, "upper");
  ASSERT_TRUE(dec.ok());
  const int lanes = 5;
  std::vector<VqDecoderState> alone(lanes, dec->NewState()), batched(lanes, dec->NewState());
  std::vector<VqDecoderState*> ptrs;
  for (auto& s : batched) ptrs.push_back(&s);
  VqDecoderScratch one = dec->NewScratch(), many = dec->NewScratch(2);  // grows on demand
  for (int step = 0; step < 6; ++step) {
    std::vector<int> codes;
    for (int b = 0; b < lanes; ++b) codes.push_back((step * 7 + b * 3) % dec->codebook_size());
    const Eigen::MatrixXf y = dec->DecodeBatch(codes, ptrs, many);
    ASSERT_EQ(y.cols(), 4 * lanes);
    for (int b = 0; b < lanes; ++b) {
      const Eigen::MatrixXf ya = dec->Decode(codes[b], alone[b], one);
      EXPECT_LT((ya - y.middleCols(4 * b, 4)).cwiseAbs().maxCoeff(), 1e-5f) << "step " << step << " lane " << b;
    }
  }
}

TEST(VqDecoder, ReferenceWholeSequenceConvolutionMatchesStreaming) {
  // A hand-made decoder: embed -> conv(k=2, dilation 1) -> upsample2 -> upsample2 (1 -> 4 frames).
  nlohmann::json ops = {{{"op", "embed_codes"}},
                        {{"op", "conv"}, {"w", "c.w"}, {"b", "c.b"}, {"dilation", 1}},
                        {{"op", "upsample2"}},
                        {{"op", "upsample2"}}};
  nlohmann::json meta;
    meta["vq"]["upper"]["decoder_ops"] = ops;
    WeightsWriter writer(meta);
  writer.Add("vq.upper.codebook", {3, 1}, {1.0f, 10.0f, 100.0f});
  writer.Add("c.w", {1, 1, 2}, {0.5f, 2.0f});  // out[t] = 0.5 in[t-1] + 2 in[t] + 1
  writer.Add("c.b", {1}, {1.0f});
  writer.Add("vq.upper.pose_mean", {1}, {0.0f});
  writer.Add("vq.upper.pose_std", {1}, {1.0f});
  absl::StatusOr<WeightsFile> f = WeightsFile::Parse(writer.Serialize());
  ASSERT_TRUE(f.ok());
  absl::StatusOr<VqDecoder> dec = VqDecoder::Load(*f, "upper");
  ASSERT_TRUE(dec.ok()) << dec.status();
  VqDecoderState st = dec->NewState();
  VqDecoderScratch sc = dec->NewScratch();
  EXPECT_FLOAT_EQ(dec->Decode(1, st, sc)(0, 3), 21.0f);          // 0.5*0 + 2*10 + 1
  EXPECT_FLOAT_EQ(dec->Decode(2, st, sc)(0, 0), 206.0f);         // 0.5*10 + 2*100 + 1
  EXPECT_FLOAT_EQ(dec->Decode(0, st, sc)(0, 2), 53.0f);          // 0.5*100 + 2*1 + 1
}

TEST(VqDecoder, RefusesBadOpLists) {
  auto load = [](nlohmann::json ops) {
    nlohmann::json meta;
    meta["vq"]["upper"]["decoder_ops"] = ops;
    WeightsWriter writer(meta);
    writer.Add("vq.upper.codebook", {3, 1}, {1.0f, 10.0f, 100.0f});
    writer.Add("vq.upper.pose_mean", {1}, {0.0f});
    writer.Add("vq.upper.pose_std", {1}, {1.0f});
    absl::StatusOr<WeightsFile> f = WeightsFile::Parse(writer.Serialize());
    return VqDecoder::Load(*f, "upper").status();
  };
  EXPECT_TRUE(absl::StrContains(load({{{"op", "relu"}}}).message(), "first op")) << load({{{"op", "relu"}}});
  EXPECT_TRUE(absl::StrContains(load({{{"op", "embed_codes"}}, {{"op", "res_begin"}}}).message(), "res_begin"));
  EXPECT_TRUE(absl::StrContains(load({{{"op", "embed_codes"}}, {{"op", "res_end"}}}).message(), "res_end"));
  EXPECT_FALSE(load({{{"op", "embed_codes"}}, {{"op", "conv"}, {"w", "nope"}, {"b", "nope"}}}).ok());
  EXPECT_FALSE(load(nlohmann::json::array()).ok());
}

}  // namespace
}  // namespace dance::engine
