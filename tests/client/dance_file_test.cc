// Unit tests of the dance writers: Euler conversion for BVH, BVH layout, dance-motion/v1 fields.
#include <cmath>
#include <random>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "client/dance_file.h"
#include "gtest/gtest.h"

namespace dance::client {
namespace {

struct M3 {
  double m[3][3];
};

M3 Mul(const M3& a, const M3& b) {
  M3 r{};
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      for (int k = 0; k < 3; ++k) r.m[i][j] += a.m[i][k] * b.m[k][j];
  return r;
}

M3 FromQuat(double w, double x, double y, double z) {
  return {{{1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)},
           {2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)},
           {2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)}}};
}

M3 FromEulerZXY(double az, double ax, double ay) {
  const double d = M_PI / 180.0;
  const double a = az * d, b = ax * d, c = ay * d;
  M3 rz{{{std::cos(a), -std::sin(a), 0}, {std::sin(a), std::cos(a), 0}, {0, 0, 1}}};
  M3 rx{{{1, 0, 0}, {0, std::cos(b), -std::sin(b)}, {0, std::sin(b), std::cos(b)}}};
  M3 ry{{{std::cos(c), 0, std::sin(c)}, {0, 1, 0}, {-std::sin(c), 0, std::cos(c)}}};
  return Mul(Mul(rz, rx), ry);
}

TEST(DanceFile, EulerZXYReproducesTheQuaternion) {
  std::mt19937 gen(5);
  std::normal_distribution<double> n;
  for (int t = 0; t < 200; ++t) {
    double w = n(gen), x = n(gen), y = n(gen), z = n(gen);
    const double len = std::sqrt(w * w + x * x + y * y + z * z);
    w /= len, x /= len, y /= len, z /= len;
    const auto e = QuaternionToEulerZXY(w, x, y, z);
    const M3 a = FromQuat(w, x, y, z), b = FromEulerZXY(e[0], e[1], e[2]);
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) ASSERT_NEAR(a.m[i][j], b.m[i][j], 1e-9) << t;
  }
}

dance::v1::SessionInfo Info() {
  dance::v1::SessionInfo info;
  info.set_fps(30);
  info.set_model_id("m");
  const int parents[24] = {-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21};
  for (int j = 0; j < 24; ++j) {
    info.mutable_skeleton()->add_joint_names(absl::StrCat("j", j));
    info.mutable_skeleton()->add_parents(parents[j]);
    for (int k = 0; k < 3; ++k) info.mutable_skeleton()->add_rest_offsets(j == 0 ? 0.0f : 0.1f);
  }
  return info;
}

std::vector<dance::v1::PoseFrame> Frames(int n) {
  std::vector<dance::v1::PoseFrame> frames(n);
  for (int i = 0; i < n; ++i) {
    frames[i].set_index(4 + i);
    frames[i].set_time_ms((4 + i) * 1000.0 / 30.0);
    for (int k = 0; k < 72; ++k) frames[i].add_positions(0.01f * k);
    for (int j = 0; j < 24; ++j) {
      frames[i].add_rotations(1);
      frames[i].add_rotations(0);
      frames[i].add_rotations(0);
      frames[i].add_rotations(0);
    }
  }
  return frames;
}

TEST(DanceFile, BvhHasEveryJointAndOneRowPerFrame) {
  const std::string bvh = DanceToBvh(Info(), Frames(3));
  EXPECT_TRUE(absl::StartsWith(bvh, "HIERARCHY\nROOT j0\n"));
  int joints = 0;
  for (absl::string_view line : absl::StrSplit(bvh, '\n')) {
    if (absl::StrContains(line, "JOINT ") || absl::StrContains(line, "ROOT ")) ++joints;
  }
  EXPECT_EQ(joints, 24);
  EXPECT_TRUE(absl::StrContains(bvh, "Frames: 3\nFrame Time: 0.033333\n"));
  const std::string motion = bvh.substr(bvh.find("Frame Time"));
  std::vector<std::string> lines = absl::StrSplit(motion, '\n', absl::SkipEmpty());
  ASSERT_EQ(lines.size(), 4u);
  std::vector<std::string> values = absl::StrSplit(lines[1], ' ', absl::SkipEmpty());
  EXPECT_EQ(values.size(), 3u + 24u * 3u);
  EXPECT_EQ(values[1], "1.0000");  // pelvis y 0.01 m = 1 cm
}

TEST(DanceFile, JsonFollowsDanceMotionV1) {
  const auto j = DanceToJson(Info(), Frames(2), 42);
  EXPECT_EQ(j["format"], "dance-motion/v1");
  EXPECT_EQ(j["fps"], 30.0);
  EXPECT_EQ(j["units"], "m");
  EXPECT_EQ(j["up_axis"], "y");
  EXPECT_EQ(j["joint_names"].size(), 24u);
  EXPECT_EQ(j["positions"].size(), 2u);
  EXPECT_EQ(j["positions"][0].size(), 24u);
  EXPECT_EQ(j["positions"][0][1].size(), 3u);
  EXPECT_NEAR(j["audio_offset_s"].get<double>(), 4.0 / 30.0, 1e-9);
  EXPECT_EQ(j["rotations"][1][23].size(), 4u);
  EXPECT_EQ(j["seed"], 42);
  EXPECT_FALSE(j.contains("beat_times_s"));  // a stream without beats
}

TEST(DanceFile, BeatEventsBecomeTheFilesBeatTimes) {
  std::vector<dance::v1::Event> events(3);
  events[0].set_kind(dance::v1::Event::KIND_BEAT);
  events[0].set_time_ms(500.4);
  events[1].set_kind(dance::v1::Event::KIND_WARNING);  // not a beat
  events[1].set_time_ms(700.0);
  events[2].set_kind(dance::v1::Event::KIND_BEAT);
  events[2].set_time_ms(1000.0);
  const std::vector<double> beats = BeatTimesOf(events);
  ASSERT_EQ(beats.size(), 2u);
  EXPECT_DOUBLE_EQ(beats[0], 0.5);
  EXPECT_DOUBLE_EQ(beats[1], 1.0);
  const auto j = DanceToJson(Info(), Frames(2), 1, beats);
  ASSERT_EQ(j["beat_times_s"].size(), 2u);
  EXPECT_DOUBLE_EQ(j["beat_times_s"][1].get<double>(), 1.0);
}

}  // namespace
}  // namespace dance::client
