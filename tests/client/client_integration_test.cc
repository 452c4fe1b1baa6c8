// Integration: the client library (PerformStream, the load tester) against a real server, and the load
// tester's frame accounting against a scripted server whose sessions fail part-way.
#include <grpcpp/grpcpp.h>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/time/clock.h"
#include "client/load_test.h"
#include "client/perform_stream.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "tests/server/testing/server_harness.h"

namespace dance::client {
namespace {

using dance::server::testing::RunEngineDirect;
using dance::server::testing::ServerHarness;
using dance::server::testing::TestSignal;
using dance::server::testing::TinyModelPath;

std::shared_ptr<const AudioClip> Clip(double seconds, int rate) {
  auto clip = std::make_shared<AudioClip>();
  clip->sample_rate = rate;
  clip->channels = 1;
  clip->samples = TestSignal(seconds, rate);
  return clip;
}

TEST(ClientIntegration, FastPerformGetsTheEngineDance) {
  ServerHarness h;
  auto stub = h.NewStub();
  auto clip = Clip(2.0, 22050);
  PerformOptions po;
  po.header.set_seed(4);
  po.chunk_ms = 25;
  PerformStream s(stub.get(), std::make_unique<ClipSource>(clip, /*realtime=*/false, 0.0), po);
  s.Start(absl::Now());
  absl::Status st = s.Wait();
  ASSERT_TRUE(st.ok()) << st;
  auto ref = RunEngineDirect(TinyModelPath(), clip->samples, 22050, 4);
  ASSERT_EQ(s.frames().size(), ref.size());
  for (size_t i = 0; i < ref.size(); ++i) {
    EXPECT_EQ(s.frames()[i].upper_code(), ref[i].upper_code());
    EXPECT_EQ(s.frames()[i].positions(11), ref[i].positions(11));
  }
  EXPECT_EQ(s.stats().gaps, 0);
  EXPECT_EQ(s.stats().latency_ms.size(), ref.size());
  EXPECT_EQ(s.end().frames(), static_cast<int64_t>(ref.size()));
}

// Load options for `streams` sessions of `duration_s` against `target`, started over `stagger_s`.
LoadOptions Load(const std::string& target, int streams, double duration_s, double stagger_s, bool realtime) {
  LoadOptions o;
  o.target = target;
  o.streams = streams;
  o.duration_s = duration_s;
  o.stagger_s = stagger_s;
  o.realtime = realtime;
  return o;
}

TEST(ClientIntegration, LoadTestReportsEveryField) {
  ServerHarness h;
  LoadOptions o = Load(h.target(), 4, 1.5, 0.2, /*realtime=*/true);
  auto r = RunLoad(o, Clip(1.0, 24000), std::cerr);  // the 1 s clip loops to 1.5 s
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_EQ(r->errors, 0) << r->first_error;
  EXPECT_EQ(r->dropped_frames, 0);
  EXPECT_GE(r->frames, 4 * 40);  // 1.5 s = 45 frames per stream, minus the first period
  // The lower bound of what the audio called for holds for the real engine (else dropped would be > 0).
  EXPECT_EQ(r->expected_frames, r->frames);
  EXPECT_GT(r->p99_ms, 0.0);
  EXPECT_GE(r->p99_ms, r->p50_ms);
  auto j = nlohmann::json::parse(LoadReportJson(*r));
  for (const char* k : {"streams", "duration_s", "frames_per_s", "errors", "dropped_frames", "expected_frames",
                        "p50_ms", "p95_ms", "p99_ms", "max_skew_ms", "max_ms", "slow_frames"}) {
    EXPECT_TRUE(j.contains(k)) << k;
  }
  EXPECT_EQ(j["slow_frames"].get<int64_t>(), r->slow_frames);
}

TEST(ClientIntegration, LoadSendsItsControlsInEveryStreamHeader) {
  ServerHarness h;
  LoadOptions o = Load(h.target(), 2, 1.0, 0.0, /*realtime=*/false);
  for (double t_ms : {0.0, 1000.0}) {
    dance::v1::PathPoint* p = o.controls.add_trajectory();
    p->set_t_ms(t_ms);
    p->set_x(static_cast<float>(t_ms / 1000.0));
  }
  auto good = RunLoad(o, Clip(1.0, 24000), std::cerr);
  ASSERT_TRUE(good.ok()) << good.status();
  EXPECT_EQ(good->errors, 0) << good->first_error;
  EXPECT_GT(good->frames, 0);
  // A path going back in time is refused by the server: so every session did send it.
  o.controls.mutable_trajectory(1)->set_t_ms(-5.0);
  auto bad = RunLoad(o, Clip(1.0, 24000), std::cerr);
  ASSERT_TRUE(bad.ok()) << bad.status();
  EXPECT_EQ(bad->errors, 2);
  EXPECT_TRUE(absl::StrContains(bad->first_error, "trajectory")) << bad->first_error;
}

TEST(LoadAccounting, SlowFramesSummarySaysWhenAndWhere) {
  LoadReport r;
  EXPECT_EQ(SlowFramesSummary(r), "slow frames (>= 100 ms): none");
  r.slow_frames = 5;
  r.slow_streams = 2;
  r.slow_server_share_p50 = 0.98;
  r.slow_by_stream_second = {{0, 1}, {30, 4}};
  r.slow_by_run_second = {{31, 5}};
  const std::string s = SlowFramesSummary(r);
  EXPECT_NE(s.find("5 in 2 streams"), std::string::npos) << s;
  EXPECT_NE(s.find("0.98"), std::string::npos) << s;
  EXPECT_NE(s.find("by second into the stream: 0s:1 30s:4"), std::string::npos) << s;
  EXPECT_NE(s.find("by second of the run: 31s:5"), std::string::npos) << s;
}

TEST(LoadAccounting, ExpectedFramesFollowTheAudioSent) {
  EXPECT_EQ(FramesForAudio(30 * 44100, 44100, 30.0, 4), 896);  // 900 frames of audio, minus the first period
  EXPECT_EQ(FramesForAudio(24000, 24000, 30.0, 4), 26);
  EXPECT_EQ(FramesForAudio(100, 24000, 30.0, 4), 0);
  EXPECT_EQ(FramesForAudio(0, 24000, 30.0, 4), 0);
  StreamTally ended;  // ended OK: the server's count rules when it is larger
  ended.received = 900;
  ended.audio_frames_sent = 30 * 44100;
  ended.sample_rate_hz = 44100;
  ended.got_end = true;
  ended.end_frames = 900;
  EXPECT_EQ(StreamExpectedFrames(ended), 900);
  EXPECT_EQ(StreamMissingFrames(ended), 0);
  ended.received = 880;
  EXPECT_EQ(StreamMissingFrames(ended), 20);
  StreamTally failed = ended;  // the issue-5 case: failed, no StreamEnd, nothing received
  failed.got_end = false;
  failed.end_frames = 0;
  failed.received = 0;
  EXPECT_EQ(StreamMissingFrames(failed), 896);
  failed.received = 10;
  failed.gaps = 2;
  EXPECT_EQ(StreamMissingFrames(failed), 886);
}

// A scripted server: SessionInfo, then `frames` frames once all audio is in, then an error instead of
// StreamEnd (what an overloaded server's idle timeout looked like to the load tester in issue 5).
class FailingDanceService final : public dance::v1::DanceService::Service {
 public:
  explicit FailingDanceService(int frames) : frames_(frames) {}
  grpc::Status Perform(grpc::ServerContext*,
                       grpc::ServerReaderWriter<dance::v1::DanceUpdate, dance::v1::PerformRequest>* stream) override {
    dance::v1::DanceUpdate info;
    info.mutable_info()->set_session_id("s-scripted");
    info.mutable_info()->set_fps(30);
    info.mutable_info()->set_frames_per_step(4);
    info.mutable_info()->set_samples_per_step(3200);
    dance::v1::PerformRequest req;
    bool info_sent = false;
    while (stream->Read(&req)) {
      if (!info_sent) info_sent = stream->Write(info);
      if (req.has_end()) break;
    }
    for (int i = 0; i < frames_; ++i) {
      dance::v1::DanceUpdate u;
      u.mutable_frame()->set_index(4 + i);
      stream->Write(u);
    }
    return grpc::Status(grpc::StatusCode::DEADLINE_EXCEEDED, "no audio for 30s (idle timeout)");
  }

 private:
  const int frames_;
};

TEST(ClientIntegration, LoadTestCountsFramesOfFailedSessionsAsDropped) {
  FailingDanceService service(/*frames=*/10);
  grpc::ServerBuilder b;
  int port = 0;
  b.AddListeningPort("127.0.0.1:0", grpc::InsecureServerCredentials(), &port);
  b.RegisterService(&service);
  std::unique_ptr<grpc::Server> server = b.BuildAndStart();
  ASSERT_NE(server, nullptr);
  ASSERT_GT(port, 0);
  // All audio is sent (not real time): the expectation is exact.
  LoadOptions o = Load(absl::StrCat("127.0.0.1:", port), 3, 1.5, 0.0, /*realtime=*/false);
  auto r = RunLoad(o, Clip(1.5, 24000), std::cerr);
  server->Shutdown();
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_EQ(r->errors, 3);
  EXPECT_EQ(r->frames, 3 * 10);
  EXPECT_EQ(r->expected_frames, 3 * (45 - 4));        // 1.5 s at 30 fps, minus the first period
  EXPECT_EQ(r->dropped_frames, 3 * (45 - 4 - 10));    // never produced, never received
  auto j = nlohmann::json::parse(LoadReportJson(*r));
  EXPECT_EQ(j["dropped_frames"], 3 * 31);
  EXPECT_TRUE(absl::StrContains(r->first_error, "idle timeout")) << r->first_error;
}

}  // namespace
}  // namespace dance::client
