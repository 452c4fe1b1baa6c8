// The .dncw reader accepts a well-formed file and refuses every kind of damage with a clear Status.
#include "engine/nn/weights_file.h"

#include <cmath>
#include <cstring>
#include <limits>

#include "absl/strings/match.h"
#include "engine/nn/crc32.h"
#include "engine/nn/weights_writer.h"
#include "gtest/gtest.h"

namespace dance::engine {
namespace {

std::vector<uint8_t> GoodFile(float special = 0.5f) {
  WeightsWriter w({{"model_id", "unit-test"}, {"hyperparameters", {{"d_model", 4}}}});
  w.Add("a.weight", {2, 3}, {1, 2, 3, 4, 5, 6});
  w.Add("b.bias", {5}, {0.1f, 0.2f, special, 0.4f, 0.5f});
  return w.Serialize();
}

// Rewrites the trailing file CRC so only the deliberate damage is detected.
void FixFileCrc(std::vector<uint8_t>& bytes) {
  const uint32_t crc = Crc32(absl::MakeConstSpan(bytes.data(), bytes.size() - 4));
  for (int i = 0; i < 4; ++i) bytes[bytes.size() - 4 + i] = static_cast<uint8_t>(crc >> (8 * i));
}

TEST(Crc32, MatchesZlibCheckValue) {
  const char* s = "123456789";
  EXPECT_EQ(Crc32(absl::MakeConstSpan(reinterpret_cast<const uint8_t*>(s), 9)), 0xCBF43926u);
  EXPECT_EQ(Crc32Update(Crc32(absl::MakeConstSpan(reinterpret_cast<const uint8_t*>(s), 4)),
                        absl::MakeConstSpan(reinterpret_cast<const uint8_t*>(s) + 4, 5)),
            0xCBF43926u);
}

TEST(WeightsFile, ReadsWhatTheWriterWrote) {
  absl::StatusOr<WeightsFile> f = WeightsFile::Parse(GoodFile());
  ASSERT_TRUE(f.ok()) << f.status();
  EXPECT_EQ(f->metadata()["model_id"], "unit-test");
  absl::StatusOr<const Tensor*> a = f->Get("a.weight", {2, 3});
  ASSERT_TRUE(a.ok()) << a.status();
  EXPECT_EQ((*a)->data[5], 6.0f);
  EXPECT_EQ(f->Find("b.bias")->data[2], 0.5f);
  EXPECT_EQ(f->Find("missing"), nullptr);
}

TEST(WeightsFile, GetReportsMissingAndWrongShape) {
  absl::StatusOr<WeightsFile> f = WeightsFile::Parse(GoodFile());
  ASSERT_TRUE(f.ok());
  EXPECT_EQ(f->Get("nope", {1}).status().code(), absl::StatusCode::kNotFound);
  absl::Status s = f->Get("a.weight", {3, 2}).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_TRUE(absl::StrContains(s.message(), "[2, 3]")) << s;
}

TEST(WeightsFile, RefusesTruncatedFiles) {
  const std::vector<uint8_t> good = GoodFile();
  for (size_t keep : {size_t{0}, size_t{3}, size_t{19}, size_t{100}, good.size() / 2, good.size() - 1}) {
    std::vector<uint8_t> bad(good.begin(), good.begin() + keep);
    absl::StatusOr<WeightsFile> f = WeightsFile::Parse(bad);
    EXPECT_FALSE(f.ok()) << "kept " << keep;
  }
}

TEST(WeightsFile, RefusesWrongMagic) {
  std::vector<uint8_t> bad = GoodFile();
  bad[0] = 'X';
  absl::Status s = WeightsFile::Parse(bad).status();
  EXPECT_TRUE(absl::StrContains(s.message(), "magic")) << s;
}

TEST(WeightsFile, RefusesWrongVersion) {
  std::vector<uint8_t> bad = GoodFile();
  bad[4] = 2;
  absl::Status s = WeightsFile::Parse(bad).status();
  EXPECT_TRUE(absl::StrContains(s.message(), "version 2")) << s;
}

TEST(WeightsFile, RefusesFlippedDataByteByFileCrc) {
  std::vector<uint8_t> bad = GoodFile();
  bad[bad.size() - 10] ^= 0x40;
  absl::Status s = WeightsFile::Parse(bad).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss);
  EXPECT_TRUE(absl::StrContains(s.message(), "CRC")) << s;
}

TEST(WeightsFile, RefusesFlippedDataByteByTensorCrc) {
  std::vector<uint8_t> bad = GoodFile();
  bad[bad.size() - 10] ^= 0x40;  // inside b.bias
  FixFileCrc(bad);
  absl::Status s = WeightsFile::Parse(bad).status();
  EXPECT_TRUE(absl::StrContains(s.message(), "tensor 'b.bias': CRC-32 mismatch")) << s;
}

TEST(WeightsFile, RefusesHeaderShapeThatDisagreesWithNbytes) {
  std::vector<uint8_t> bad = GoodFile();
  std::string text(bad.begin(), bad.end());
  const size_t pos = text.find("[2,3]");
  ASSERT_NE(pos, std::string::npos);
  bad[pos + 3] = '4';  // shape [2, 4]: 32 bytes, but nbytes says 24
  FixFileCrc(bad);
  absl::Status s = WeightsFile::Parse(bad).status();
  EXPECT_TRUE(absl::StrContains(s.message(), "nbytes")) << s;
}

TEST(WeightsFile, RefusesNanAndInf) {
  for (float special : {std::numeric_limits<float>::quiet_NaN(), std::numeric_limits<float>::infinity()}) {
    absl::Status s = WeightsFile::Parse(GoodFile(special)).status();
    EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
    EXPECT_TRUE(absl::StrContains(s.message(), "NaN/Inf")) << s;
  }
}

TEST(WeightsFile, RefusesGarbageHeader) {
  std::vector<uint8_t> bad = GoodFile();
  bad[16] = '#';  // the JSON's opening brace
  FixFileCrc(bad);
  EXPECT_FALSE(WeightsFile::Parse(bad).ok());
}

TEST(WeightsFile, LoadReportsMissingFile) {
  absl::Status s = WeightsFile::Load("/nonexistent/x.dncw").status();
  EXPECT_EQ(s.code(), absl::StatusCode::kNotFound);
}

}  // namespace
}  // namespace dance::engine
