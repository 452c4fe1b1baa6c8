// The .dncw reader accepts a well-formed file and refuses every kind of damage with a clear Status.
#include "engine/nn/weights_file.h"

#include <cmath>
#include <cstring>
#include <limits>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
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

// Values exactly representable in binary16: zero, -0, subnormals, the smallest normal, max-normal, ordinary.
const std::vector<float> kHalfValues = {0.0f,
                                        -0.0f,
                                        std::ldexp(1.0f, -24),     // smallest subnormal
                                        -std::ldexp(1.0f, -24),
                                        std::ldexp(1023.0f, -24),  // largest subnormal
                                        std::ldexp(1.0f, -14),     // smallest normal
                                        65504.0f,                  // max normal
                                        -65504.0f,
                                        1.0f,
                                        -0.3330078125f,
                                        1.5f * std::ldexp(1.0f, -10),
                                        1234.0f};

std::vector<uint8_t> HalfFile(const std::vector<float>& values) {
  WeightsWriter w(nlohmann::json{{"model_id", "unit-test"}});
  w.Add("h.weight", {static_cast<int64_t>(values.size() / 2), 2}, values, WeightsWriter::Dtype::kF16);
  w.Add("b.bias", {2}, {0.25f, -1.0f});  // f32 beside it
  return w.Serialize();
}

uint32_t Bits(float x) {
  uint32_t b;
  std::memcpy(&b, &x, 4);
  return b;
}

TEST(WeightsFile, ReadsF16TensorsExactlyAsFloat32) {
  const std::vector<uint8_t> bytes = HalfFile(kHalfValues);
  EXPECT_TRUE(absl::StrContains(std::string(bytes.begin(), bytes.end()), "\"dtype\":\"f16\""));
  absl::StatusOr<WeightsFile> f = WeightsFile::Parse(bytes);
  ASSERT_TRUE(f.ok()) << f.status();
  absl::StatusOr<const Tensor*> h = f->Get("h.weight", {6, 2});
  ASSERT_TRUE(h.ok()) << h.status();
  ASSERT_EQ((*h)->data.size(), kHalfValues.size());
  for (size_t i = 0; i < kHalfValues.size(); ++i) {
    EXPECT_EQ(Bits((*h)->data[i]), Bits(kHalfValues[i])) << "value " << i << " = " << kHalfValues[i];
  }
  EXPECT_EQ(f->Find("b.bias")->data[1], -1.0f);
}

TEST(WeightsFile, F16StoresTwoBytesAndRoundsToNearest) {
  WeightsWriter w(nlohmann::json::object());
  w.Add("h", {2}, {0.1f, 1.0f + std::ldexp(1.0f, -11)}, WeightsWriter::Dtype::kF16);  // 0.1 -> 0x2E66; tie -> 1
  const std::vector<uint8_t> bytes = w.Serialize();
  EXPECT_TRUE(absl::StrContains(std::string(bytes.begin(), bytes.end()), "\"nbytes\":4,"));
  absl::StatusOr<WeightsFile> f = WeightsFile::Parse(bytes);
  ASSERT_TRUE(f.ok()) << f.status();
  EXPECT_EQ(f->Find("h")->data[0], 0.0999755859375f);
  EXPECT_EQ(f->Find("h")->data[1], 1.0f);
}

TEST(WeightsFile, RefusesF16NbytesOfTheWrongSize) {
  std::vector<uint8_t> bad = HalfFile(kHalfValues);
  std::string text(bad.begin(), bad.end());
  const size_t pos = text.find("\"nbytes\":24,");  // 12 halves
  ASSERT_NE(pos, std::string::npos);
  bad[pos + 9] = '4';
  bad[pos + 10] = '8';  // "nbytes":48, the size the 12 values would have as f32
  FixFileCrc(bad);
  absl::Status s = WeightsFile::Parse(bad).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss);
  EXPECT_TRUE(absl::StrContains(s.message(), "tensor 'h.weight': nbytes 48 != 2 * product[6, 2] (dtype f16)"))
      << s;
}

TEST(WeightsFile, RefusesInfAndNanHalves) {
  for (float special : {std::numeric_limits<float>::infinity(), -1e6f, std::numeric_limits<float>::quiet_NaN()}) {
    std::vector<float> values = kHalfValues;
    values[7] = special;  // Inf half (0x7C00 / 0xFC00, -1e6 overflows) or NaN half (0x7E00)
    absl::Status s = WeightsFile::Parse(HalfFile(values)).status();
    EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
    EXPECT_TRUE(absl::StrContains(s.message(), "tensor 'h.weight': value 7 is")) << s;
    EXPECT_TRUE(absl::StrContains(s.message(), "NaN/Inf not allowed")) << s;
  }
}

TEST(WeightsFile, UnknownDtypeListsTheSupportedOnes) {
  for (const char* dtype : {"\"i32\"", "\"f64\"", "12345"}) {  // as long as "f32", so the layout stays
    std::vector<uint8_t> bad = GoodFile();
    std::string text(bad.begin(), bad.end());
    const size_t pos = text.find("\"f32\"");
    ASSERT_NE(pos, std::string::npos);
    std::memcpy(bad.data() + pos, dtype, 5);
    FixFileCrc(bad);
    absl::Status s = WeightsFile::Parse(bad).status();
    EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << s;
    EXPECT_TRUE(absl::StrContains(s.message(), absl::StrCat("tensor 'a.weight': dtype ", dtype, " unsupported")))
        << s;
    EXPECT_TRUE(absl::StrContains(s.message(), "(supported: \"f32\", \"f16\")")) << s;
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
