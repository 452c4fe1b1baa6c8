// Integration: the live controls (docs/controls.md, "Live") through a real dance-server on port 0 running
// the shipped model (it has the VQ encoders that read given motion), real gRPC channels: controls in the
// StreamHeader, Control.controls and Control.steer mid-stream, PoseInput from a "mocap rig", and the
// errors and warnings of bad control input.
#include <algorithm>
#include <cmath>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "absl/time/clock.h"
#include "gtest/gtest.h"
#include "tests/server/testing/server_harness.h"

namespace dance::server::testing {
namespace {

constexpr char kModel[] = "models/default.dncw";
constexpr int kRate = 24000;
constexpr int kSamplesPerFrame = kRate / 30;

using Pose = std::vector<float>;  // 24 x 3

// One Perform call with a reader thread, so the test can interleave what it sends with what comes back.
class Call {
 public:
  explicit Call(dance::v1::DanceService::Stub* stub) : stream_(stub->Perform(&ctx_)) {
    reader_ = std::thread([this] {
      dance::v1::DanceUpdate u;
      while (stream_->Read(&u)) {
        std::lock_guard<std::mutex> lock(mu_);
        if (u.has_info()) info_ = u.info();
        if (u.has_frame()) frames_.push_back(u.frame());
        if (u.has_event()) events_.push_back(u.event());
      }
    });
  }
  ~Call() {
    if (reader_.joinable()) Finish();
  }

  bool Write(const dance::v1::PerformRequest& r) { return stream_->Write(r); }
  void Header(const dance::v1::MotionControls* controls, uint64_t seed = 1) {
    dance::v1::PerformRequest r;
    dance::v1::StreamHeader* h = r.mutable_header();
    h->set_sample_rate_hz(kRate);
    h->set_channels(1);
    h->set_sample_format(dance::v1::SAMPLE_FORMAT_F32LE);
    h->set_seed(seed);
    if (controls != nullptr) *h->mutable_controls() = *controls;
    Write(r);
  }
  // Audio samples [from, to) of `audio`, in chunks of at most 0.2 s.
  bool Audio(const std::vector<float>& audio, size_t from, size_t to) {
    bool ok = true;
    for (size_t a = from; ok && a < to; a += 4800) {
      const size_t b = std::min(to, a + 4800);
      dance::v1::PerformRequest r;
      r.mutable_audio()->set_sample_offset(static_cast<int64_t>(a));
      r.mutable_audio()->set_pcm(reinterpret_cast<const char*>(audio.data() + a), (b - a) * sizeof(float));
      ok = Write(r);
    }
    return ok;
  }
  void End() {
    dance::v1::PerformRequest r;
    r.mutable_end();
    Write(r);
  }
  grpc::Status Finish() {
    stream_->WritesDone();
    reader_.join();
    return stream_->Finish();
  }
  std::vector<dance::v1::PoseFrame> frames() {
    std::lock_guard<std::mutex> lock(mu_);
    return frames_;
  }
  std::vector<dance::v1::Event> events() {
    std::lock_guard<std::mutex> lock(mu_);
    return events_;
  }
  dance::v1::SessionInfo info() {
    std::lock_guard<std::mutex> lock(mu_);
    return info_;
  }

 private:
  grpc::ClientContext ctx_;
  std::unique_ptr<grpc::ClientReaderWriter<dance::v1::PerformRequest, dance::v1::DanceUpdate>> stream_;
  std::thread reader_;
  std::mutex mu_;
  dance::v1::SessionInfo info_;
  std::vector<dance::v1::PoseFrame> frames_;
  std::vector<dance::v1::Event> events_;
};

Pose PoseOf(const dance::v1::PoseFrame& f) { return Pose(f.positions().begin(), f.positions().end()); }

// Joint j of `p` in the body frame of its hips (pelvis at the origin, the hips' facing along +Z), as the
// engine composites a given half without its pelvis.
std::array<double, 3> InHipFrame(const Pose& p, int j) {
  const double ax = p[3 * 1 + 0] - p[3 * 2 + 0], az = p[3 * 1 + 2] - p[3 * 2 + 2];  // left_hip - right_hip
  const double yaw = std::atan2(-az, ax);
  const double dx = p[3 * j] - p[0], dy = p[3 * j + 1] - p[1], dz = p[3 * j + 2] - p[2];
  const double c = std::cos(yaw), s = std::sin(yaw);
  return {c * dx - s * dz, dy, s * dx + c * dz};
}

// The frame of index m (frames are consecutive from their first index).
const dance::v1::PoseFrame& At(const std::vector<dance::v1::PoseFrame>& frames, int64_t m) {
  return frames.at(static_cast<size_t>(m - frames.front().index()));
}

bool HasEvent(const std::vector<dance::v1::Event>& events, dance::v1::Event::Kind kind, const std::string& text) {
  for (const auto& e : events) {
    if (e.kind() == kind && e.message().find(text) != std::string::npos) return true;
  }
  return false;
}

std::string EventText(const std::vector<dance::v1::Event>& events) {
  std::vector<std::string> lines;
  for (const auto& e : events) lines.push_back(absl::StrCat(e.kind(), ": ", e.message()));
  return absl::StrJoin(lines, "\n");
}

class ControlsIntegration : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    harness_ = new ServerHarness(nullptr, kModel);
    audio_ = new std::vector<float>(TestSignal(7.0, kRate));
    // The free dance (no controls) every test compares with: seed 1, as the calls below.
    auto stub = harness_->NewStub();
    Call c(stub.get());
    c.Header(nullptr);
    c.Audio(*audio_, 0, audio_->size());
    c.End();
    const grpc::Status st = c.Finish();
    ASSERT_TRUE(st.ok()) << st.error_message();
    free_ = new std::vector<dance::v1::PoseFrame>(c.frames());
    ASSERT_GT(free_->size(), 200u);
  }
  static void TearDownTestSuite() {
    delete free_;
    delete audio_;
    delete harness_;
  }

  static ServerHarness* harness_;
  static std::vector<float>* audio_;
  static std::vector<dance::v1::PoseFrame>* free_;
};
ServerHarness* ControlsIntegration::harness_ = nullptr;
std::vector<float>* ControlsIntegration::audio_ = nullptr;
std::vector<dance::v1::PoseFrame>* ControlsIntegration::free_ = nullptr;

TEST_F(ControlsIntegration, HeaderSeedAndKeyframesComeOutAsGiven) {
  // Seed: the free dance's frames 90..119 placed at 0 s; keyframes: its frame 200 at 3 s and at 5 s,
  // sent as a dance-motion/v1 file.
  dance::v1::MotionControls mc;
  for (int i = 90; i < 120; ++i) {
    for (float v : (*free_)[i].positions()) mc.mutable_seed()->add_positions(v);
  }
  const Pose key = PoseOf(At(*free_, 200));
  std::vector<std::string> joints;
  for (int j = 0; j < 24; ++j) joints.push_back(absl::StrCat("[", key[3 * j], ",", key[3 * j + 1], ",", key[3 * j + 2], "]"));
  const std::string pose_json = absl::StrCat("[", absl::StrJoin(joints, ","), "]");
  mc.mutable_keyframes()->set_file(absl::StrCat(R"({"format": "dance-motion/v1", "fps": 30, "times_s": [3.0, 5.0], )",
                                                R"("positions": [)", pose_json, ",", pose_json, "]}"));
  auto stub = harness_->NewStub();
  Call c(stub.get());
  c.Header(&mc);
  c.Audio(*audio_, 0, audio_->size());
  c.End();
  const grpc::Status st = c.Finish();
  ASSERT_TRUE(st.ok()) << st.error_message();
  const std::vector<dance::v1::PoseFrame> frames = c.frames();
  ASSERT_EQ(frames.size(), free_->size());
  double seed_err = 0.0, key_err = 0.0, free_to_key = 0.0;
  // (frames start at index 4: the first step's period has no pose)
  for (const auto& f : frames) {
    if (f.index() >= 30) break;
    for (int k = 0; k < 72; ++k) {
      seed_err = std::max(seed_err, std::abs(double{f.positions(k)} - (*free_)[90 + f.index()].positions(k)));
    }
  }
  for (int m : {90, 150}) {
    const dance::v1::PoseFrame& out = At(frames, m);
    for (int k = 0; k < 72; ++k) {
      key_err = std::max(key_err, std::abs(double{out.positions(k)} - key[k]));
      free_to_key = std::max(free_to_key, std::abs(double{At(*free_, m).positions(k)} - key[k]));
    }
  }
  EXPECT_LT(seed_err, 1e-4) << "the seed's frames come out exactly as given";
  EXPECT_LT(key_err, 1e-4) << "the key poses are hit on time";
  EXPECT_GT(free_to_key, 0.05) << "the free dance is elsewhere there (so the check can fail)";
}

TEST_F(ControlsIntegration, BadHeaderControlsAreInvalidArgumentNamingTheField) {
  auto stub = harness_->NewStub();
  {
    dance::v1::MotionControls mc;
    for (int i = 0; i < 71; ++i) mc.mutable_seed()->add_positions(0.1f);
    Call c(stub.get());
    c.Header(&mc);
    const grpc::Status st = c.Finish();
    EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
    EXPECT_NE(st.error_message().find("controls.seed.positions"), std::string::npos) << st.error_message();
  }
  {
    dance::v1::MotionControls mc;  // key poses one frame apart: closer than one step
    for (int i = 0; i < 2; ++i) {
      for (float v : (*free_)[100].positions()) mc.mutable_keyframes()->add_positions(v);
      mc.mutable_keyframes()->add_times_ms(1000.0 + i * 33.4);
    }
    Call c(stub.get());
    c.Header(&mc);
    const grpc::Status st = c.Finish();
    EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
    EXPECT_NE(st.error_message().find("keyframes"), std::string::npos) << st.error_message();
  }
  {
    dance::v1::MotionControls mc;  // a path out of time order
    for (double t : {2000.0, 1000.0}) {
      dance::v1::PathPoint* p = mc.add_trajectory();
      p->set_t_ms(t);
    }
    Call c(stub.get());
    c.Header(&mc);
    const grpc::Status st = c.Finish();
    EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
    EXPECT_NE(st.error_message().find("trajectory"), std::string::npos) << st.error_message();
  }
}

TEST_F(ControlsIntegration, SteerPointBringsTheDancerThere) {
  // Mid-stream, after 2 s: be 1.5 m off the free dance's 5-s position (in x and z) at 5 s.
  const Pose free5 = PoseOf(At(*free_, 150));
  const float tx = free5[0] + 1.5f, tz = free5[2] + 1.5f;
  auto stub = harness_->NewStub();
  Call c(stub.get());
  c.Header(nullptr);
  c.Audio(*audio_, 0, 2 * kRate);
  dance::v1::PerformRequest r;
  dance::v1::PathPoint* p = r.mutable_control()->mutable_steer()->mutable_point();
  p->set_t_ms(5000.0);
  p->set_x(tx);
  p->set_z(tz);
  c.Write(r);
  c.Audio(*audio_, 2 * kRate, audio_->size());
  c.End();
  const grpc::Status st = c.Finish();
  ASSERT_TRUE(st.ok()) << st.error_message();
  const std::vector<dance::v1::PoseFrame> frames = c.frames();
  ASSERT_EQ(frames.size(), free_->size());
  EXPECT_TRUE(HasEvent(c.events(), dance::v1::Event::KIND_CONTROL_APPLIED, "")) << EventText(c.events());
  // From 5 s on the path holds the target (its end).
  double worst = 0.0;
  for (int m = 150; m < 180; ++m) {
    worst = std::max(worst, double{std::hypot(At(frames, m).positions(0) - tx, At(frames, m).positions(2) - tz)});
  }
  EXPECT_LT(worst, 0.35) << "root distance from the target, m";
  EXPECT_GT(std::hypot(free5[0] - tx, free5[2] - tz), 2.0);
  // Before the control took effect nothing changed (the audio went as fast as the server takes it, so it
  // may take effect from the first steps on).
  int64_t applied = -1;
  for (const auto& e : c.events()) {
    if (e.kind() == dance::v1::Event::KIND_CONTROL_APPLIED) applied = e.frame_index();
  }
  ASSERT_GE(applied, 0);
  for (size_t i = 0; i < static_cast<size_t>(applied); ++i) {
    for (int k = 0; k < 72; ++k) ASSERT_EQ(frames[i].positions(k), (*free_)[i].positions(k)) << "frame " << i;
  }
}

TEST_F(ControlsIntegration, LivePosesOfTheUpperBodyComeOutAsGiven) {
  // A "mocap rig" sends the free dance of seed 1 as the upper body of a session with seed 2, one pose per
  // frame, with the audio: the upper body follows the rig exactly (relative to the hips), the lower body
  // is the model's own.
  auto stub = harness_->NewStub();
  Call c(stub.get());
  c.Header(nullptr, /*seed=*/2);
  const size_t n_frames = audio_->size() / kSamplesPerFrame;
  for (size_t m = 0; m < n_frames; ++m) {
    if (m >= 4 && m - 4 < free_->size()) {  // the rig's poses: the free dance's frame m
      dance::v1::PerformRequest r;
      dance::v1::PoseInput* pose = r.mutable_poses();
      pose->set_time_ms(m * 1000.0 / 30.0);
      pose->set_part(dance::v1::BODY_PART_UPPER);
      *pose->mutable_positions() = At(*free_, static_cast<int64_t>(m)).positions();
      c.Write(r);
    }
    c.Audio(*audio_, m * kSamplesPerFrame, (m + 1) * kSamplesPerFrame);
  }
  c.End();
  const grpc::Status st = c.Finish();
  ASSERT_TRUE(st.ok()) << st.error_message();
  EXPECT_GT(c.info().pose_latency_ms(), 0.0);
  const std::vector<dance::v1::PoseFrame> frames = c.frames();
  ASSERT_EQ(frames.size(), free_->size());
  const int upper[] = {3, 6, 9, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22, 23};
  double err = 0.0, lower_diff = 0.0;
  for (size_t i = 10; i + 10 < frames.size(); ++i) {
    const Pose out = PoseOf(frames[i]), given = PoseOf(At(*free_, frames[i].index()));
    for (int j : upper) {
      const auto a = InHipFrame(out, j), b = InHipFrame(given, j);
      for (int k = 0; k < 3; ++k) err = std::max(err, std::abs(a[k] - b[k]));
    }
    lower_diff = std::max(lower_diff, double{std::abs(out[3 * 7 + 1] - given[3 * 7 + 1])});  // left ankle height
  }
  EXPECT_LT(err, 1e-3) << "upper joints relative to the hips, m";
  EXPECT_GT(lower_diff, 0.01) << "the legs are the model's own (seed 2), not the rig's";
  EXPECT_FALSE(HasEvent(c.events(), dance::v1::Event::KIND_WARNING, "")) << EventText(c.events());
}

TEST_F(ControlsIntegration, PoseInputThatStopsEndsTheGivenPartWithAWarning) {
  auto stub = harness_->NewStub();
  Call c(stub.get());
  c.Header(nullptr, /*seed=*/2);
  const size_t n_frames = audio_->size() / kSamplesPerFrame;
  for (size_t m = 0; m < n_frames; ++m) {
    if (m >= 4 && m < 45) {  // the rig stops after 1.5 s; the music goes on
      dance::v1::PerformRequest r;
      r.mutable_poses()->set_time_ms(m * 1000.0 / 30.0);
      r.mutable_poses()->set_part(dance::v1::BODY_PART_UPPER);
      *r.mutable_poses()->mutable_positions() = At(*free_, static_cast<int64_t>(m)).positions();
      c.Write(r);
    }
    c.Audio(*audio_, m * kSamplesPerFrame, (m + 1) * kSamplesPerFrame);
    // The music goes on in time: 1.5 s later the server has waited out its pose timeout (1 s).
    if (m == 100) absl::SleepFor(absl::Milliseconds(1500));
  }
  // A malformed pose later: refused with a warning, the session goes on.
  dance::v1::PerformRequest bad;
  bad.mutable_poses()->set_time_ms(6000.0);
  bad.mutable_poses()->set_part(dance::v1::BODY_PART_UPPER);
  bad.mutable_poses()->add_positions(1.0f);
  c.Write(bad);
  c.End();
  const grpc::Status st = c.Finish();
  ASSERT_TRUE(st.ok()) << st.error_message();
  EXPECT_EQ(c.frames().size(), free_->size()) << "every frame still comes";
  const std::vector<dance::v1::Event> events = c.events();
  EXPECT_TRUE(HasEvent(events, dance::v1::Event::KIND_WARNING, "pose input stopped")) << EventText(events);
  EXPECT_TRUE(HasEvent(events, dance::v1::Event::KIND_WARNING, "poses.positions")) << EventText(events);
}

TEST_F(ControlsIntegration, BadMidStreamControlIsAWarningAndTheDanceGoesOn) {
  auto stub = harness_->NewStub();
  Call c(stub.get());
  c.Header(nullptr);
  c.Audio(*audio_, 0, kRate);
  dance::v1::PerformRequest r;
  dance::v1::PathPoint* p = r.mutable_control()->mutable_steer()->mutable_point();
  p->set_t_ms(0.0);  // before the next frame: refused
  c.Write(r);
  r.Clear();
  r.mutable_control()->mutable_controls()->mutable_seed()->set_file("not a motion file");
  c.Write(r);
  c.Audio(*audio_, kRate, audio_->size());
  c.End();
  const grpc::Status st = c.Finish();
  ASSERT_TRUE(st.ok()) << st.error_message();
  const std::vector<dance::v1::PoseFrame> frames = c.frames();
  ASSERT_EQ(frames.size(), free_->size());
  for (size_t m = 0; m < frames.size(); ++m) {
    for (int k = 0; k < 72; ++k) ASSERT_EQ(frames[m].positions(k), (*free_)[m].positions(k)) << "frame " << m;
  }
  const std::vector<dance::v1::Event> events = c.events();
  EXPECT_TRUE(HasEvent(events, dance::v1::Event::KIND_WARNING, "steer.point.t_ms")) << EventText(events);
  EXPECT_TRUE(HasEvent(events, dance::v1::Event::KIND_WARNING, "controls.seed")) << EventText(events);
}

}  // namespace
}  // namespace dance::server::testing
