// Controls (engine/runtime/controls.h) on the shipped model: seed motion, given halves, keyframes,
// inpainting and a trajectory keep what is given exactly and dance the rest; bad input is refused with a
// clear error; snapshots and chunking stay exact with controls on.
#include "engine/runtime/controls.h"

#include <cmath>
#include <filesystem>
#include <fstream>
#include <memory>
#include <vector>

#include "absl/strings/match.h"
#include "engine/engine.h"
#include "gtest/gtest.h"
#include "tests/engine/runtime/testing/session_run.h"
#include "tests/engine/runtime/testing/tiny_model.h"

namespace dance::engine {
namespace {

std::shared_ptr<const Model> Shipped() {
  static std::shared_ptr<const Model> model = [] {
    absl::StatusOr<std::shared_ptr<const Model>> m = LoadModel("models/default.dncw");
    EXPECT_TRUE(m.ok()) << m.status() << " (run from the source root)";
    return m.ok() ? *m : nullptr;
  }();
  return model;
}

const std::vector<float>& Audio() {
  static const std::vector<float> audio = testing::ClickAudio(24.0, 96.0);
  return audio;
}

std::vector<PoseFrame> Dance(const Controls& controls, size_t chunk = 4096, uint64_t seed = 3) {
  SessionOptions options;
  options.seed = seed;
  options.style = {{"waltz", 1.0f}};
  options.controls = controls;
  absl::StatusOr<std::unique_ptr<Session>> s = Session::Create(Shipped(), options);
  EXPECT_TRUE(s.ok()) << s.status();
  if (!s.ok()) return {};
  return testing::RunStream(**s, Audio(), {chunk});
}

TrajectoryPoint Point(double t, float x = 0.0f, float z = 0.0f) {
  TrajectoryPoint p;
  p.t_s = t;
  p.x = x;
  p.z = z;
  return p;
}

// The reference dance the controls are taken from: the model's own, with another seed.
const std::vector<PoseFrame>& Reference() {
  static const std::vector<PoseFrame> ref = Dance({}, 4096, /*seed=*/11);
  return ref;
}

std::vector<JointPositions> PositionsOf(const std::vector<PoseFrame>& frames, size_t from, size_t n) {
  std::vector<JointPositions> out;
  for (size_t i = from; i < from + n && i < frames.size(); ++i) out.push_back(frames[i].positions);
  return out;
}

double HipYaw(const JointPositions& p) {
  const Eigen::Vector3f a = p[1] - p[2];
  return std::atan2(-a.z(), a.x());
}

// p relative to its pelvis, in the frame of its hips.
Eigen::Vector3f InHipFrame(const JointPositions& p, int j) {
  const double y = HipYaw(p), c = std::cos(y), s = std::sin(y);
  const Eigen::Vector3f d = p[j] - p[0];
  return Eigen::Vector3f(static_cast<float>(c * d.x() - s * d.z()), d.y(), static_cast<float>(s * d.x() + c * d.z()));
}

// The largest joint speed (m/s) from frame a to frame b of `f`.
double MaxSpeed(const std::vector<PoseFrame>& f, size_t a, size_t b) {
  double best = 0.0;
  for (size_t i = std::max<size_t>(a, 1); i < b && i < f.size(); ++i) {
    for (int j = 0; j < kNumJoints; ++j) best = std::max(best, 30.0 * (f[i].positions[j] - f[i - 1].positions[j]).norm());
  }
  return best;
}

// The 95th percentile over frames of the largest joint speed of a dance.
double P95Speed(const std::vector<PoseFrame>& f) {
  std::vector<double> s;
  for (size_t i = 1; i < f.size(); ++i) s.push_back(MaxSpeed(f, i, i + 1));
  std::sort(s.begin(), s.end());
  return s[s.size() * 95 / 100];
}

TEST(Controls, SeedMotionIsKeptExactlyAndTheDanceGoesOnWithoutASeam) {
  ASSERT_NE(Shipped(), nullptr);
  const std::vector<PoseFrame>& ref = Reference();
  ASSERT_GT(ref.size(), 600u);
  Controls c;
  c.motion = SeedTrack(PositionsOf(ref, 100, 60), ref[100].index);  // 2 s from 3.47 s on
  const std::vector<PoseFrame> out = Dance(c);
  ASSERT_EQ(out.size(), ref.size());
  for (size_t i = 100; i < 160; ++i) {
    for (int j = 0; j < kNumJoints; ++j) ASSERT_EQ(out[i].positions[j], ref[i].positions[j]) << i << " " << j;
  }
  // The seam: no faster than the dance's own 95th percentile of speed.
  EXPECT_LT(MaxSpeed(out, 158, 175), P95Speed(out));
  // And it dances after it (not a held pose), differently from the reference.
  EXPECT_GT(MaxSpeed(out, 200, 400), 0.5);
  double apart = 0.0;
  for (size_t i = 200; i < 400; ++i) apart += (out[i].positions[20] - ref[i].positions[20]).norm();
  EXPECT_GT(apart / 200, 0.05);
}

TEST(Controls, GivenHalvesComeOutAsGivenAndMeetAtThePelvis) {
  ASSERT_NE(Shipped(), nullptr);
  const std::vector<PoseFrame>& ref = Reference();
  for (bool upper : {true, false}) {
    Controls c;
    c.motion = GivenHalfTrack(PositionsOf(ref, 0, ref.size()), ref[0].index, upper);
    const std::vector<PoseFrame> out = Dance(c);
    ASSERT_EQ(out.size(), ref.size());
    double worst = 0.0, other_apart = 0.0;
    for (size_t i = 0; i < out.size(); ++i) {
      if (upper) {
        for (int j : kUpperJoints) worst = std::max(worst, static_cast<double>((InHipFrame(out[i].positions, j) - InHipFrame(ref[i].positions, j)).norm()));
        other_apart += (InHipFrame(out[i].positions, 10) - InHipFrame(ref[i].positions, 10)).norm();
      } else {
        for (int j : kLowerJoints) worst = std::max(worst, static_cast<double>((out[i].positions[j] - ref[i].positions[j]).norm()));
        other_apart += (InHipFrame(out[i].positions, 20) - InHipFrame(ref[i].positions, 20)).norm();
      }
      // The halves meet: spine1 stays its bone length from the pelvis.
      ASSERT_NEAR((out[i].positions[3] - out[i].positions[0]).norm(), (ref[i].positions[3] - ref[i].positions[0]).norm(), 1e-4);
    }
    EXPECT_LT(worst, 2e-4) << (upper ? "upper" : "lower") << " half, metres";
    // The other half is danced anew (it differs from the reference's).
    EXPECT_GT(other_apart / out.size(), 0.02) << (upper ? "upper" : "lower");
  }
}

TEST(Controls, KeyframesAreHitOnTimeAndTheDanceMovesBetweenThem) {
  ASSERT_NE(Shipped(), nullptr);
  const std::vector<PoseFrame>& ref = Reference();
  std::vector<int64_t> frames;
  std::vector<JointPositions> poses;
  for (size_t i = 90; i + 30 < ref.size(); i += 90) {
    frames.push_back(ref[i].index);
    poses.push_back(ref[i].positions);
  }
  absl::StatusOr<MotionTrack> keys = KeyframeTrack(poses, frames);
  ASSERT_TRUE(keys.ok()) << keys.status();
  Controls c;
  c.motion = *keys;
  const std::vector<PoseFrame> out = Dance(c);
  for (size_t k = 0; k < frames.size(); ++k) {
    const PoseFrame& f = out[frames[k] - out[0].index];
    for (int j = 0; j < kNumJoints; ++j) ASSERT_EQ(f.positions[j], poses[k][j]) << "key " << k << " joint " << j;
  }
  EXPECT_GT(MaxSpeed(out, 100, 170), 0.5);
  // Seams: within 3x the dance's own 95th percentile of speed (measured 1-2x; docs/controls.md).
  for (int64_t key : frames) {
    const size_t i = key - out[0].index;
    EXPECT_LT(MaxSpeed(out, i - 15, i + 15), 3.0 * P95Speed(out)) << "key at frame " << key;
  }
}

TEST(Controls, InpaintingKeepsTheKnownPartAndRedancesTheRest) {
  ASSERT_NE(Shipped(), nullptr);
  const std::vector<PoseFrame>& ref = Reference();
  std::vector<JointMask> known(ref.size(), kAllJoints);
  for (size_t i = 200; i < 400; ++i) known[i] = 0;
  Controls c;
  c.motion = MaskedTrack(PositionsOf(ref, 0, ref.size()), ref[0].index, known);
  const std::vector<PoseFrame> out = Dance(c);
  double redanced = 0.0;
  for (size_t i = 0; i < out.size(); ++i) {
    if (known[i] == kAllJoints) {
      for (int j = 0; j < kNumJoints; ++j) ASSERT_EQ(out[i].positions[j], ref[i].positions[j]) << i;
    } else {
      redanced += (out[i].positions[20] - ref[i].positions[20]).norm();
    }
  }
  EXPECT_GT(redanced / 200, 0.05);
  EXPECT_LT(MaxSpeed(out, 190, 215), 3.0 * P95Speed(out));
  EXPECT_LT(MaxSpeed(out, 385, 410), 3.0 * P95Speed(out));
}

TEST(Controls, TrajectoryIsFollowed) {
  ASSERT_NE(Shipped(), nullptr);
  Controls c;
  for (int t = 0; t <= 24; ++t) c.trajectory.push_back(Point(static_cast<double>(t), 0.25f * t, 0.0f));
  const std::vector<PoseFrame> free = Dance({});
  const std::vector<PoseFrame> out = Dance(c);
  double err = 0.0, free_err = 0.0;
  int n = 0;
  for (size_t i = 60; i < out.size(); ++i) {
    const double target = 0.25 * out[i].time_s;
    err += std::hypot(out[i].positions[0].x() - target, out[i].positions[0].z());
    free_err += std::hypot(free[i].positions[0].x() - target, free[i].positions[0].z());
    ++n;
  }
  err /= n;
  free_err /= n;
  std::printf("trajectory: mean root distance %.3f m (unconstrained %.3f m)\n", err, free_err);
  EXPECT_LT(err, 0.2);
  EXPECT_LT(err, 0.25 * free_err);
}

TEST(Controls, SnapshotsAndChunkingStayExactWithControls) {
  ASSERT_NE(Shipped(), nullptr);
  const std::vector<PoseFrame>& ref = Reference();
  Controls c;
  c.motion = SeedTrack(PositionsOf(ref, 0, 90), ref[0].index);
  absl::StatusOr<MotionTrack> keys = KeyframeTrack({ref[400].positions}, {ref[400].index});
  ASSERT_TRUE(keys.ok());
  c.motion = CombineTracks(c.motion, *keys);
  c.trajectory = {Point(0.0, 0.0f, 0.0f), Point(20.0, 2.0f, 1.0f)};
  const std::vector<PoseFrame> a = Dance(c, 4096);
  const std::vector<PoseFrame> b = Dance(c, 777);
  ASSERT_EQ(a.size(), b.size());
  for (size_t i = 0; i < a.size(); ++i) ASSERT_EQ(a[i].positions[20], b[i].positions[20]) << i;
  // Snapshot mid-stream, restore into a fresh session, continue: the same frames.
  SessionOptions options;
  options.seed = 3;
  options.style = {{"waltz", 1.0f}};
  options.controls = c;
  auto s = Session::Create(Shipped(), options);
  ASSERT_TRUE(s.ok());
  const std::vector<float>& audio = Audio();
  const size_t half = audio.size() / 2;
  ASSERT_TRUE((*s)->PushAudio(absl::MakeConstSpan(audio.data(), half)).ok());
  while ((*s)->StepsReady() > 0) ASSERT_TRUE((*s)->Step().ok());
  std::vector<PoseFrame> got;
  (*s)->PopFrames(&got);
  absl::StatusOr<SessionSnapshot> snap = (*s)->Snapshot();
  ASSERT_TRUE(snap.ok());
  auto t = Session::Create(Shipped(), options);
  ASSERT_TRUE(t.ok());
  ASSERT_TRUE((*t)->Restore(*snap).ok());
  ASSERT_TRUE((*t)->PushAudio(absl::MakeConstSpan(audio.data() + half, audio.size() - half)).ok());
  (*t)->EndOfAudio();
  while ((*t)->StepsReady() > 0) ASSERT_TRUE((*t)->Step().ok());
  (*t)->PopFrames(&got);
  ASSERT_EQ(got.size(), a.size());
  for (size_t i = 0; i < a.size(); ++i) ASSERT_EQ(got[i].positions[20], a[i].positions[20]) << i;
}

TEST(Controls, SetMidStreamTravelInSnapshotsAndBadOnesChangeNothing) {
  ASSERT_NE(Shipped(), nullptr);
  SessionOptions options;
  options.seed = 3;
  options.style = {{"waltz", 1.0f}};
  const std::vector<float>& audio = Audio();
  const size_t half = audio.size() / 2;  // 12 s
  auto first_half = [&](Session& s) {
    EXPECT_TRUE(s.PushAudio(absl::MakeConstSpan(audio.data(), half)).ok());
    while (s.StepsReady() > 0) EXPECT_TRUE(s.Step().ok());
  };
  auto second_half = [&](Session& s, std::vector<PoseFrame>* out) {
    EXPECT_TRUE(s.PushAudio(absl::MakeConstSpan(audio.data() + half, audio.size() - half)).ok());
    s.EndOfAudio();
    while (s.StepsReady() > 0) EXPECT_TRUE(s.Step().ok());
    s.PopFrames(out);
  };
  const std::vector<PoseFrame> free = Dance({});
  auto s = Session::Create(Shipped(), options);
  ASSERT_TRUE(s.ok());
  first_half(**s);
  std::vector<PoseFrame> out;
  (*s)->PopFrames(&out);
  const size_t before = out.size();
  // A bad update is refused and changes nothing.
  Controls bad;
  bad.trajectory = {Point(14.0), Point(13.0)};
  EXPECT_EQ((*s)->SetControls(bad).code(), absl::StatusCode::kInvalidArgument);
  // A path from where the dancer is now to 3 m along +x by the end.
  const Eigen::Vector3f here = out.back().positions[0];
  Controls path;
  path.trajectory = {Point(12.5, here.x(), here.z()), Point(23.0, here.x() + 3.0f, here.z())};
  ASSERT_TRUE((*s)->SetControls(path).ok());
  absl::StatusOr<SessionSnapshot> snap = (*s)->Snapshot();
  ASSERT_TRUE(snap.ok());
  second_half(**s, &out);
  ASSERT_EQ(out.size(), free.size());
  for (size_t i = 0; i < before; ++i) ASSERT_EQ(out[i].positions[20], free[i].positions[20]) << i;
  const PoseFrame& end = out[(23.0 - out[0].time_s) * 30];
  EXPECT_LT(std::hypot(end.positions[0].x() - (here.x() + 3.0f), end.positions[0].z() - here.z()), 0.3);
  // The controls travel in the snapshot: a session created without them continues the same.
  auto t = Session::Create(Shipped(), options);
  ASSERT_TRUE(t.ok());
  ASSERT_TRUE((*t)->Restore(*snap).ok());
  std::vector<PoseFrame> rest;
  second_half(**t, &rest);
  ASSERT_EQ(rest.size(), out.size() - before);
  for (size_t i = 0; i < rest.size(); ++i) ASSERT_EQ(rest[i].positions[20], out[before + i].positions[20]) << i;
  // Reset returns to the creation controls (none): the free dance again.
  (*t)->Reset();
  std::vector<PoseFrame> again;
  first_half(**t);
  second_half(**t, &again);
  ASSERT_EQ(again.size(), free.size());
  for (size_t i = 0; i < again.size(); ++i) ASSERT_EQ(again[i].positions[20], free[i].positions[20]) << i;
}

TEST(Controls, BadInputIsRefusedWithAClearError) {
  ASSERT_NE(Shipped(), nullptr);
  const std::vector<PoseFrame>& ref = Reference();
  SessionOptions options;
  auto refused = [&](const Controls& c, const std::string& words) {
    options.controls = c;
    absl::StatusOr<std::unique_ptr<Session>> s = Session::Create(Shipped(), options);
    ASSERT_FALSE(s.ok()) << words;
    EXPECT_EQ(s.status().code(), absl::StatusCode::kInvalidArgument) << s.status();
    EXPECT_TRUE(absl::StrContains(s.status().message(), words)) << s.status();
  };
  Controls nan;
  nan.motion = SeedTrack(PositionsOf(ref, 0, 8), 4);
  nan.motion.positions[3][7].x() = std::nanf("");
  refused(nan, "frame 3 joint 7");
  Controls far;
  far.motion = SeedTrack(PositionsOf(ref, 0, 8), 4);
  far.motion.positions[2][0].y() = 5000.0f;
  refused(far, "within 100 m");
  Controls shape;
  shape.motion = SeedTrack(PositionsOf(ref, 0, 8), 4);
  shape.motion.known.pop_back();
  refused(shape, "masks");
  Controls order;
  order.trajectory = {Point(2.0), Point(1.0)};
  refused(order, "not after point 0");
  EXPECT_FALSE(KeyframeTrack({ref[0].positions, ref[1].positions}, {10, 12}).ok());
  EXPECT_TRUE(absl::StrContains(KeyframeTrack({ref[0].positions, ref[1].positions}, {10, 12}).status().message(),
                                "closer than one step"));
}

TEST(Controls, MotionFilesReadBackWhatTheWritersWrote) {
  ASSERT_NE(Shipped(), nullptr);
  const std::vector<PoseFrame>& ref = Reference();
  const std::vector<PoseFrame> clip(ref.begin(), ref.begin() + 40);
  const std::filesystem::path dir = std::filesystem::temp_directory_path();
  const std::string json = (dir / "controls_test_clip.json").string(), bvh = (dir / "controls_test_clip.bvh").string();
  ASSERT_TRUE(WriteDanceJson(json, Shipped()->skeleton(), clip, DanceInfo{}).ok());
  ASSERT_TRUE(WriteBvh(bvh, Shipped()->skeleton(), clip).ok());
  absl::StatusOr<MotionFile> a = ReadMotionFile(json);
  ASSERT_TRUE(a.ok()) << a.status();
  EXPECT_EQ(a->first_frame, clip[0].index);
  absl::StatusOr<MotionFile> b = ReadMotionFile(bvh);
  ASSERT_TRUE(b.ok()) << b.status();
  ASSERT_EQ(a->positions.size(), clip.size());
  ASSERT_EQ(b->positions.size(), clip.size());
  double json_err = 0.0, bvh_err = 0.0;
  for (size_t i = 0; i < clip.size(); ++i) {
    for (int j = 0; j < kNumJoints; ++j) {
      json_err = std::max(json_err, static_cast<double>((a->positions[i][j] - clip[i].positions[j]).norm()));
      bvh_err = std::max(bvh_err, static_cast<double>((b->positions[i][j] - clip[i].positions[j]).norm()));
    }
  }
  EXPECT_LT(json_err, 2e-6);  // 6 decimals
  // The BVH carries rotations: single-child bones come back exactly, the three children of the pelvis and
  // of spine3 (one rotation each) within 2 cm (measured 1.7 cm).
  EXPECT_LT(bvh_err, 0.025) << "metres";
  // A BVH of another skeleton names what it lacks.
  absl::StatusOr<MotionFile> other = ParseBvh("HIERARCHY\nROOT Hips\n{\nOFFSET 0 0 0\nCHANNELS 3 Xposition Yposition Zposition\n}\nMOTION\nFrames: 1\nFrame Time: 0.033\n0 0 0\n");
  ASSERT_FALSE(other.ok());
  EXPECT_TRUE(absl::StrContains(other.status().message(), "missing joints: pelvis")) << other.status();
  // A position channel on an axis that does not exist is refused (found by motion_fuzz in a 10 M-run:
  // "Wposition" indexed the translation out of bounds).
  std::ifstream bvh_in(bvh);
  std::string text((std::istreambuf_iterator<char>(bvh_in)), std::istreambuf_iterator<char>());
  const size_t x = text.find("Xposition");
  ASSERT_NE(x, std::string::npos);
  text[x] = 'W';
  absl::StatusOr<MotionFile> bad_axis = ParseBvh(text);
  ASSERT_FALSE(bad_axis.ok());
  EXPECT_TRUE(absl::StrContains(bad_axis.status().message(), "unknown channel 'Wposition'")) << bad_axis.status();
  std::filesystem::remove(json);
  std::filesystem::remove(bvh);
  // Fields of the wrong type are errors, not exceptions (found by motion_fuzz: "format" as a list).
  EXPECT_EQ(ParseMaskJson(R"({"format": [1], "known": []})", *a).status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(ParseMotionJson(R"({"format": "dance-motion/v1", "fps": "thirty", "positions": []})").status().code(),
            absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(ParseTrajectoryJson(R"({"format": 7, "points": []})").status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(ParseMotionJson(R"({"format": "dance-motion/v1", "positions": [[[0, 1, 0]]]})").status().code(),
            absl::StatusCode::kInvalidArgument);  // 1 joint, not 24
}

}  // namespace
}  // namespace dance::engine
