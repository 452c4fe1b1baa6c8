#include "engine/audio/npy_writer.h"

#include <cstdio>
#include <fstream>
#include <string>
#include <vector>

#include "gtest/gtest.h"

namespace dance::engine::audio {
namespace {

TEST(NpyWriter, RoundTripsAndAlignsHeader) {
  const std::string path = ::testing::TempDir() + "/x.npy";
  std::vector<float> data(3 * 5);
  for (size_t i = 0; i < data.size(); ++i) data[i] = 0.5f * i - 2.0f;
  ASSERT_TRUE(WriteNpyFloat32(path, data, 3, 5).ok());
  std::ifstream in(path, std::ios::binary | std::ios::ate);
  const auto size = static_cast<size_t>(in.tellg());
  EXPECT_EQ((size - data.size() * 4) % 64, 0u);
  absl::StatusOr<NpyArray> back = ReadNpyFloat32(path);
  ASSERT_TRUE(back.ok()) << back.status();
  EXPECT_EQ(back->rows, 3);
  EXPECT_EQ(back->cols, 5);
  EXPECT_EQ(back->data, data);
}

TEST(NpyWriter, RejectsShapeMismatchAndBadPath) {
  std::vector<float> data(6);
  EXPECT_EQ(WriteNpyFloat32(::testing::TempDir() + "/y.npy", data, 4, 2).code(),
            absl::StatusCode::kInvalidArgument);
  EXPECT_FALSE(WriteNpyFloat32("/nonexistent-dir/x.npy", data, 2, 3).ok());
  EXPECT_EQ(ReadNpyFloat32("/nonexistent-dir/x.npy").status().code(), absl::StatusCode::kNotFound);
}

TEST(NpyWriter, EmptyArray) {
  const std::string path = ::testing::TempDir() + "/empty.npy";
  ASSERT_TRUE(WriteNpyFloat32(path, {}, 0, 108).ok());
  absl::StatusOr<NpyArray> back = ReadNpyFloat32(path);
  ASSERT_TRUE(back.ok());
  EXPECT_EQ(back->rows, 0);
  EXPECT_EQ(back->cols, 108);
}

}  // namespace
}  // namespace dance::engine::audio
