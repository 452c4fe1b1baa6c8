// Integration: the client library (PerformStream, the load tester) against a real server.
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

TEST(ClientIntegration, LoadTestReportsEveryField) {
  ServerHarness h;
  LoadOptions o;
  o.target = h.target();
  o.streams = 4;
  o.duration_s = 1.5;
  o.stagger_s = 0.2;
  auto r = RunLoad(o, Clip(1.0, 24000), std::cerr);  // the 1 s clip loops to 1.5 s
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_EQ(r->errors, 0) << r->first_error;
  EXPECT_EQ(r->dropped_frames, 0);
  EXPECT_GE(r->frames, 4 * 40);  // 1.5 s = 45 frames per stream, minus the first period
  EXPECT_GT(r->p99_ms, 0.0);
  EXPECT_GE(r->p99_ms, r->p50_ms);
  auto j = nlohmann::json::parse(LoadReportJson(*r));
  for (const char* k : {"streams", "duration_s", "frames_per_s", "errors", "dropped_frames", "p50_ms", "p95_ms",
                        "p99_ms", "max_skew_ms"}) {
    EXPECT_TRUE(j.contains(k)) << k;
  }
}

}  // namespace
}  // namespace dance::client
