// Unit tests of the server's pure parts: validation, JSON, WebSocket handshake, metrics, sinks; and the
// scheduler over a labelled test double engine (no model, fixed step cost).
#include <map>
#include <memory>
#include <thread>

#include "absl/strings/match.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/clock.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "server/core/live_session.h"
#include "server/core/metrics.h"
#include "server/core/scheduler.h"
#include "server/core/update.h"
#include "server/grpc/convert.h"
#include "server/web/json_codec.h"
#include "server/web/prometheus.h"
#include "server/web/websocket.h"
#include "server/web/ws_sink.h"

namespace dance::server {
namespace {

ModelDescription Model() {
  ModelDescription m;
  m.styles = {"breaking", "popping"};
  return m;
}

dance::v1::StreamHeader GoodHeader() {
  dance::v1::StreamHeader h;
  h.set_sample_rate_hz(44100);
  h.set_channels(2);
  h.set_sample_format(dance::v1::SAMPLE_FORMAT_S16LE);
  return h;
}

TEST(WebSocket, AcceptKeyMatchesRfc6455Example) {
  EXPECT_EQ(WebSocketAcceptKey("dGhlIHNhbXBsZSBub25jZQ=="), "s3pPLMBiTxaQ9kYGzzhZRbK+xOo=");
}

TEST(Convert, ValidHeaderIsAccepted) {
  auto v = ValidateHeader(GoodHeader(), Model(), {});
  ASSERT_TRUE(v.ok()) << v.status();
  EXPECT_EQ(v->config.sample_rate_hz, 44100);
  EXPECT_EQ(v->format, PcmFormat::kS16Le);
  EXPECT_LT(v->config.sampling.top_p, 0.0f);  // 0 (unset): the model's default
  EXPECT_FALSE(v->config.sampling.period_lock.has_value());  // absent: unset (the model's default, or kept)
  auto h = GoodHeader();
  h.mutable_sampling()->set_period_lock(0.0f);  // present and 0: off, not "default"
  v = ValidateHeader(h, Model(), {});
  ASSERT_TRUE(v.ok()) << v.status();
  EXPECT_EQ(v->config.sampling.period_lock, 0.0f);
  h.mutable_sampling()->set_period_lock(12.0f);
  EXPECT_EQ(ValidateHeader(h, Model(), {})->config.sampling.period_lock, 12.0f);
  h.mutable_sampling()->set_period_lock(-1.0f);  // asked for: the model's default (negative for the engine)
  v = ValidateHeader(h, Model(), {});
  ASSERT_TRUE(v.ok()) << v.status();
  ASSERT_TRUE(v->config.sampling.period_lock.has_value());
  EXPECT_LT(*v->config.sampling.period_lock, 0.0f);
  // Guidance 0 (unset) is the model's default (negative for the engine); 1 is off; others as given.
  EXPECT_LT(v->config.sampling.guidance, 0.0f);
  h.mutable_sampling()->set_guidance(1.0f);
  EXPECT_EQ(ValidateHeader(h, Model(), {})->config.sampling.guidance, 1.0f);
  h.mutable_sampling()->set_guidance(3.0f);
  EXPECT_EQ(ValidateHeader(h, Model(), {})->config.sampling.guidance, 3.0f);
  h.mutable_sampling()->set_top_p(0.9f);
  EXPECT_EQ(ValidateHeader(h, Model(), {})->config.sampling.top_p, 0.9f);
  // Music guidance: absent = the model's default (unset); 0 is a weight (the music mean alone); -1 asks
  // for the default (negative for the engine).
  EXPECT_FALSE(v->config.sampling.music_guidance.has_value());
  h.mutable_sampling()->set_music_guidance(0.0f);
  EXPECT_EQ(ValidateHeader(h, Model(), {})->config.sampling.music_guidance, 0.0f);
  h.mutable_sampling()->set_music_guidance(0.5f);
  EXPECT_EQ(ValidateHeader(h, Model(), {})->config.sampling.music_guidance, 0.5f);
  h.mutable_sampling()->set_music_guidance(-1.0f);
  EXPECT_LT(*ValidateHeader(h, Model(), {})->config.sampling.music_guidance, 0.0f);
  h.mutable_sampling()->clear_music_guidance();
  // The foot lock is on unless the header asks for raw feet.
  EXPECT_TRUE(v->config.foot_lock);
  h.set_raw_feet(true);
  EXPECT_FALSE(ValidateHeader(h, Model(), {})->config.foot_lock);
}

TEST(Convert, BadHeadersNameTheField) {
  auto check = [](dance::v1::StreamHeader h, const char* field) {
    auto v = ValidateHeader(h, Model(), {});
    ASSERT_FALSE(v.ok());
    EXPECT_EQ(v.status().code(), absl::StatusCode::kInvalidArgument);
    EXPECT_TRUE(absl::StrContains(v.status().message(), field)) << v.status();
  };
  auto h = GoodHeader();
  h.set_sample_rate_hz(7999);
  check(h, "sample_rate_hz");
  h = GoodHeader();
  h.set_channels(9);
  check(h, "channels");
  h = GoodHeader();
  h.set_sample_format(dance::v1::SAMPLE_FORMAT_UNSPECIFIED);
  check(h, "sample_format");
  h = GoodHeader();
  h.add_style()->set_name("waltz");
  check(h, "waltz");
  h = GoodHeader();
  h.mutable_sampling()->set_temperature(-1);
  check(h, "temperature");
  h = GoodHeader();
  h.mutable_sampling()->set_top_p(1.5f);
  check(h, "top_p");
  h = GoodHeader();
  h.mutable_sampling()->set_period_lock(-2.0f);
  check(h, "period_lock");
  h.mutable_sampling()->set_period_lock(-0.5f);
  check(h, "period_lock");
  h.mutable_sampling()->set_period_lock(101.0f);
  check(h, "period_lock");
  h = GoodHeader();
  h.mutable_sampling()->set_music_guidance(-0.5f);
  check(h, "music_guidance");
  h.mutable_sampling()->set_music_guidance(100.5f);
  check(h, "music_guidance");
}

TEST(Convert, ChunksMustBeWholeFramesWithinTheLimit) {
  auto v = ValidateHeader(GoodHeader(), Model(), {});  // s16 stereo: 4 bytes per sample frame
  StreamLimits limits;
  limits.max_chunk_samples = 100;
  EXPECT_TRUE(ValidateChunk(400, *v, limits).ok());
  EXPECT_FALSE(ValidateChunk(402, *v, limits).ok());
  EXPECT_FALSE(ValidateChunk(404, *v, limits).ok());
}

TEST(Convert, JsonStartAndControl) {
  auto h = StreamRequestFromJson(nlohmann::json::parse(
      R"({"type":"start","sample_rate":48000,"channels":1,"style":"popping","temperature":0.5,"seed":9})"));
  ASSERT_TRUE(h.ok());
  EXPECT_EQ(h->sample_rate_hz, 48000);
  EXPECT_EQ(h->seed, 9u);
  ASSERT_EQ(h->style.size(), 1u);
  EXPECT_EQ(h->style[0].first, "popping");
  ASSERT_TRUE(h->sampling.has_value());
  EXPECT_FLOAT_EQ(h->sampling->temperature, 0.5f);
  EXPECT_FALSE(h->sampling->period_lock.has_value());  // absent: the model's default
  EXPECT_EQ(h->sampling->guidance, 0.0f);              // absent: 0, the model's default
  EXPECT_EQ(h->sampling->top_p, 0.0f);
  h = StreamRequestFromJson(nlohmann::json::parse(R"({"type":"start","sample_rate":48000,"guidance":1,"top_p":0.9})"));
  ASSERT_TRUE(h.ok());
  ASSERT_TRUE(h->sampling.has_value());
  EXPECT_EQ(h->sampling->guidance, 1.0f);
  EXPECT_FLOAT_EQ(h->sampling->top_p, 0.9f);
  EXPECT_FALSE(h->sampling->music_guidance.has_value());  // absent: the model's default
  h = StreamRequestFromJson(nlohmann::json::parse(R"({"type":"start","sample_rate":48000,"music_guidance":0.5})"));
  ASSERT_TRUE(h.ok());
  ASSERT_TRUE(h->sampling.has_value());
  ASSERT_TRUE(h->sampling->music_guidance.has_value());
  EXPECT_EQ(*h->sampling->music_guidance, 0.5f);
  EXPECT_FALSE(StreamRequestFromJson(nlohmann::json::parse(R"({"sample_rate":48000,"music_guidance":"less"})")).ok());
  h = StreamRequestFromJson(nlohmann::json::parse(R"({"type":"start","sample_rate":48000,"period_lock":0})"));
  ASSERT_TRUE(h.ok());
  ASSERT_TRUE(h->sampling.has_value());
  ASSERT_TRUE(h->sampling->period_lock.has_value());
  EXPECT_EQ(*h->sampling->period_lock, 0.0f);
  EXPECT_FALSE(h->raw_feet);
  h = StreamRequestFromJson(nlohmann::json::parse(R"({"type":"start","sample_rate":48000,"raw_feet":true})"));
  ASSERT_TRUE(h.ok());
  EXPECT_TRUE(h->raw_feet);
  EXPECT_FALSE(StreamRequestFromJson(nlohmann::json::parse(R"({"sample_rate":"fast"})")).ok());
  auto c = ControlRequestFromJson(
      nlohmann::json::parse(R"({"type":"control","style":[{"name":"breaking","weight":2}]})"));
  ASSERT_TRUE(c.ok());
  EXPECT_EQ(c->style[0].second, 2.0f);
  EXPECT_FALSE(c->sampling.has_value());
  ModelDescription m = Model();
  m.default_guidance = 3.0f;
  m.default_top_p = 0.9f;
  m.default_music_guidance = 0.5f;
  m.style_period_lock = {{"waltz", 0.0f}, {"tango", 8.0f}};
  const nlohmann::json mj = ModelToJson(m);
  EXPECT_EQ(mj["default_guidance"].get<float>(), 3.0f);
  EXPECT_EQ(mj["style_period_lock"]["waltz"].get<float>(), 0.0f);
  EXPECT_EQ(mj["style_period_lock"]["tango"].get<float>(), 8.0f);
  EXPECT_FLOAT_EQ(mj["default_top_p"].get<float>(), 0.9f);
  EXPECT_EQ(mj["default_music_guidance"].get<float>(), 0.5f);
}

UpdatePtr Frame(int64_t index, double time_s) {
  FrameUpdate f{};
  f.pose.index = index;
  f.pose.time_s = time_s;
  f.pose.positions.fill(0.5f);
  f.pose.rotations.fill(1.0f);
  f.pose.upper_code = 3;
  f.pose.lower_code = 7;
  return std::make_shared<const Update>(f);
}

TEST(Convert, FrameJsonHasTheDocumentedFields) {
  const UpdatePtr u = Frame(4, 0.13325);
  std::string scratch;
  auto j = nlohmann::json::parse(UpdateToJson(*u, /*with_rotations=*/true, 0, &scratch));
  EXPECT_EQ(j["type"], "frame");
  EXPECT_EQ(j["index"], 4);
  EXPECT_EQ(j["time_ms"], 133.25);
  EXPECT_EQ(j["positions"].size(), 72u);
  EXPECT_TRUE(j.contains("upper_code"));
  EXPECT_TRUE(j.contains("dropped_before"));
}

TEST(Metrics, HistogramBucketsAreCumulative) {
  Histogram hist({0.001, 0.01, 0.1});
  hist.Observe(0.0005);
  hist.Observe(0.005);
  hist.Observe(0.005);
  hist.Observe(5.0);
  std::string out;
  RenderHistogram(hist, "x", "help", &out);
  EXPECT_TRUE(absl::StrContains(out, "x_bucket{le=\"0.001\"} 1\n"));
  EXPECT_TRUE(absl::StrContains(out, "x_bucket{le=\"0.01\"} 3\n"));
  EXPECT_TRUE(absl::StrContains(out, "x_bucket{le=\"0.1\"} 3\n"));
  EXPECT_TRUE(absl::StrContains(out, "x_bucket{le=\"+Inf\"} 4\n"));
  EXPECT_TRUE(absl::StrContains(out, "x_count 4\n"));
  EXPECT_DOUBLE_EQ(hist.ApproxQuantile(0.5), 0.01);
}

TEST(Metrics, ErrorsAreCountedByKind) {
  ServerMetrics m;
  m.CountError(absl::StatusCode::kResourceExhausted);
  m.CountError(absl::StatusCode::kResourceExhausted);
  const std::string text = RenderPrometheus(m, 3, 10, false);
  EXPECT_TRUE(absl::StrContains(text, "dance_errors_total{kind=\"resource_exhausted\"} 2\n"));
  EXPECT_TRUE(absl::StrContains(text, "dance_sessions_active 3\n"));
}

UpdatePtr Frame(int64_t index) {
  FrameUpdate f{};
  f.pose.index = index;
  return std::make_shared<const Update>(f);
}

TEST(WsSink, LossyKeepsTheNewestFramesAndCountsDrops) {
  ServerMetrics m;
  WsSink sink(/*lossy=*/true, /*limit=*/2, true, &m);
  for (int i = 0; i < 5; ++i) sink.Deliver(Frame(i));
  sink.Close(absl::OkStatus());
  UpdatePtr u;
  int64_t dropped_before = -1;
  absl::Status final;
  ASSERT_TRUE(sink.Next(&u, &dropped_before, &final));
  EXPECT_EQ(u->frame()->pose.index, 3);
  EXPECT_EQ(dropped_before, 3);
  ASSERT_TRUE(sink.Next(&u, &dropped_before, &final));
  EXPECT_EQ(u->frame()->pose.index, 4);
  EXPECT_EQ(dropped_before, 0);
  EXPECT_FALSE(sink.Next(&u, &dropped_before, &final));
  EXPECT_TRUE(final.ok());
  EXPECT_EQ(m.viewer_frames_dropped_total.load(), 3u);
}

TEST(WsSink, LosslessOverflowFailsWithResourceExhausted) {
  ServerMetrics m;
  WsSink sink(/*lossy=*/false, /*limit=*/3, true, &m);
  for (int i = 0; i < 4; ++i) sink.Deliver(Frame(i));
  UpdatePtr u;
  int64_t dropped_before = 0;
  absl::Status final;
  EXPECT_FALSE(sink.Next(&u, &dropped_before, &final));
  EXPECT_EQ(final.code(), absl::StatusCode::kResourceExhausted);
}

// ---- Scheduler over a test double engine ----
// TEST DOUBLE: a step is ready per 3200 input samples (24 kHz mono), costs `step_cost` of wall time in
// StepBatch (a sleep: the scheduler is busy, the CPU is not) and emits 4 frames.
class FakeStream : public EngineStream {
 public:
  absl::Status PushAudio(absl::Span<const float> s) override {
    samples_ += static_cast<int64_t>(s.size());
    return absl::OkStatus();
  }
  absl::Status PushAudioInt16(absl::Span<const int16_t> s) override {
    samples_ += static_cast<int64_t>(s.size());
    return absl::OkStatus();
  }
  void EndOfAudio() override { samples_ = (samples_ + 3199) / 3200 * 3200; }
  int StepsReady() const override { return static_cast<int>(samples_ / 3200 - steps_); }
  void PopFrames(std::vector<FrameData>* out) override {
    for (; popped_ < steps_ * 4; ++popped_) {
      FrameData f{};
      f.index = popped_;
      out->push_back(f);
    }
  }
  absl::Status SetStyle(const StyleMix&) override { return absl::OkStatus(); }
  absl::Status SetSampling(const SamplingConfig&) override { return absl::OkStatus(); }
  void Step() { ++steps_; }

 private:
  int64_t samples_ = 0;
  int64_t steps_ = 0;
  int64_t popped_ = 0;
};

class FakeBackend : public EngineBackend {
 public:
  explicit FakeBackend(absl::Duration step_cost) : step_cost_(step_cost) {}
  const ModelDescription& Describe() const override { return model_; }
  absl::StatusOr<std::unique_ptr<EngineStream>> Open(const StreamConfig&) const override {
    return std::make_unique<FakeStream>();
  }
  absl::Status StepBatch(absl::Span<EngineStream* const> streams) const override {
    absl::SleepFor(step_cost_);
    for (EngineStream* s : streams) static_cast<FakeStream*>(s)->Step();
    return absl::OkStatus();
  }

 private:
  const absl::Duration step_cost_;
  ModelDescription model_;
};

class Completions {
 public:
  void Record(const std::string& id, const absl::Status& st) {
    absl::MutexLock lock(&mu_);
    done_[id] = st;
    order_.push_back(id);
  }
  // Waits (generously) until `id` completed; its status, or DEADLINE_EXCEEDED("test: ...") if it never did.
  absl::Status Wait(const std::string& id, absl::Duration timeout = absl::Seconds(60)) {
    absl::MutexLock lock(&mu_);
    auto has = [&]() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_) { return done_.count(id) > 0; };
    if (!mu_.AwaitWithTimeout(absl::Condition(&has), timeout)) return absl::DeadlineExceededError("test: not done");
    return done_[id];
  }
  std::vector<std::string> order() {
    absl::MutexLock lock(&mu_);
    return order_;
  }

 private:
  absl::Mutex mu_;
  std::map<std::string, absl::Status> done_ ABSL_GUARDED_BY(mu_);
  std::vector<std::string> order_ ABSL_GUARDED_BY(mu_);
};

std::shared_ptr<LiveSession> NewSession(const FakeBackend& backend, Scheduler* sched, ServerMetrics* metrics,
                                        const std::string& id, absl::Duration idle_timeout) {
  SessionSettings st;
  st.id = id;
  st.idle_timeout = idle_timeout;
  st.wake = [sched] { sched->Wake(); };
  return std::make_shared<LiveSession>(st, *backend.Open({}), backend.Describe(), metrics, absl::Now());
}

absl::Status Feed(LiveSession& s, int64_t offset, int64_t samples) {
  bool pause = false;
  return s.EnqueueAudio(offset, std::string(static_cast<size_t>(samples) * sizeof(float), '\0'), absl::Now(),
                        &pause);
}

// Issue 5: under overload a session whose client kept sending ended with an idle timeout: the scheduler
// was busy stepping others (a pass lasted as long as any step was ready), the new session sat in its
// incoming list undrained, and idle time was measured against the last *drained* chunk. Now the idle
// time runs from the last chunk's arrival, and every pass is one step round, so new sessions and
// timeouts are handled while the engine is behind.
TEST(Scheduler, IdleTimeoutCountsArrivalsNotDrainsAndBusyPassesStayShort) {
  ServerMetrics metrics;
  FakeBackend backend(absl::Milliseconds(50));
  Completions done;
  Scheduler sched(&backend, &metrics, {}, [&](LiveSession& s, const absl::Status& st) { done.Record(s.id(), st); });
  sched.Start();
  // The hog: 60 steps queued at once, >= 3 s of scheduler time.
  auto hog = NewSession(backend, &sched, &metrics, "hog", absl::Seconds(30));
  ASSERT_TRUE(Feed(*hog, 0, 60 * 3200).ok());
  ASSERT_TRUE(hog->EnqueueEnd(absl::Now()).ok());
  sched.Add(hog);
  for (int i = 0; i < 6000 && metrics.steps_total.load() == 0; ++i) absl::SleepFor(absl::Milliseconds(1));
  ASSERT_GT(metrics.steps_total.load(), 0u);
  // A real-time client joining while the hog runs (20 ms chunks for 2.5 s, idle timeout 1.5 s), and one
  // that never sends anything (idle timeout 300 ms).
  auto live = NewSession(backend, &sched, &metrics, "live", absl::Milliseconds(1500));
  auto silent = NewSession(backend, &sched, &metrics, "silent", absl::Milliseconds(300));
  sched.Add(live);
  sched.Add(silent);
  std::thread feeder([&] {
    const absl::Time t0 = absl::Now();
    int64_t off = 0;
    while (absl::Now() - t0 < absl::Milliseconds(2500)) {
      if (!Feed(*live, off, 480).ok()) return;
      off += 480;
      absl::SleepFor(absl::Milliseconds(20));
    }
    (void)live->EnqueueEnd(absl::Now());
  });
  const absl::Status silent_st = done.Wait("silent");
  const absl::Status live_st = done.Wait("live");
  const absl::Status hog_st = done.Wait("hog");
  feeder.join();
  EXPECT_EQ(silent_st.code(), absl::StatusCode::kDeadlineExceeded) << silent_st;
  EXPECT_TRUE(absl::StrContains(silent_st.message(), "idle timeout")) << silent_st;
  EXPECT_TRUE(live_st.ok()) << live_st;
  EXPECT_TRUE(hog_st.ok()) << hog_st;
  // The silent one timed out while the hog was still being stepped (timeouts are not starved).
  const std::vector<std::string> order = done.order();
  ASSERT_EQ(order.size(), 3u);
  EXPECT_EQ(order.front(), "silent");
  sched.Stop();
}

}  // namespace
}  // namespace dance::server
