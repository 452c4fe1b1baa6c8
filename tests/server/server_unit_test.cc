// Unit tests of the server's pure parts: validation, JSON, WebSocket handshake, metrics, sinks.
#include <memory>

#include "absl/strings/match.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "server/convert.h"
#include "server/metrics.h"
#include "server/websocket.h"
#include "server/ws_sink.h"

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
  EXPECT_EQ(v->config.sampling.top_p, 1.0f);
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
  auto h = HeaderFromJson(nlohmann::json::parse(
      R"({"type":"start","sample_rate":48000,"channels":1,"style":"popping","temperature":0.5,"seed":9})"));
  ASSERT_TRUE(h.ok());
  EXPECT_EQ(h->sample_rate_hz(), 48000);
  EXPECT_EQ(h->seed(), 9u);
  ASSERT_EQ(h->style_size(), 1);
  EXPECT_EQ(h->style(0).name(), "popping");
  EXPECT_FLOAT_EQ(h->sampling().temperature(), 0.5f);
  EXPECT_FALSE(HeaderFromJson(nlohmann::json::parse(R"({"sample_rate":"fast"})")).ok());
  auto c = ControlFromJson(nlohmann::json::parse(R"({"type":"control","style":[{"name":"breaking","weight":2}]})"));
  ASSERT_TRUE(c.ok());
  EXPECT_EQ(c->style(0).weight(), 2.0f);
  EXPECT_FALSE(c->has_sampling());
}

TEST(Convert, FrameJsonHasTheDocumentedFields) {
  dance::v1::DanceUpdate u;
  u.mutable_frame()->set_index(4);
  u.mutable_frame()->set_time_ms(133.25);
  for (int i = 0; i < 72; ++i) u.mutable_frame()->add_positions(0.5f);
  auto j = nlohmann::json::parse(UpdateToJson(u));
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
  hist.Render("x", "help", &out);
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
  const std::string text = m.RenderPrometheus(3, 10, false);
  EXPECT_TRUE(absl::StrContains(text, "dance_errors_total{kind=\"resource_exhausted\"} 2\n"));
  EXPECT_TRUE(absl::StrContains(text, "dance_sessions_active 3\n"));
}

UpdatePtr Frame(int64_t index) {
  auto u = std::make_shared<dance::v1::DanceUpdate>();
  u->mutable_frame()->set_index(index);
  return u;
}

TEST(WsSink, LossyKeepsTheNewestFramesAndCountsDrops) {
  ServerMetrics m;
  WsSink sink(/*lossy=*/true, /*limit=*/2, true, &m);
  for (int i = 0; i < 5; ++i) sink.Deliver(Frame(i));
  sink.Close(absl::OkStatus());
  UpdatePtr u;
  absl::Status final;
  ASSERT_TRUE(sink.Next(&u, &final));
  EXPECT_EQ(u->frame().index(), 3);
  EXPECT_EQ(u->frame().dropped_before(), 3);
  ASSERT_TRUE(sink.Next(&u, &final));
  EXPECT_EQ(u->frame().index(), 4);
  EXPECT_EQ(u->frame().dropped_before(), 0);
  EXPECT_FALSE(sink.Next(&u, &final));
  EXPECT_TRUE(final.ok());
  EXPECT_EQ(m.viewer_frames_dropped_total.load(), 3u);
}

TEST(WsSink, LosslessOverflowFailsWithResourceExhausted) {
  ServerMetrics m;
  WsSink sink(/*lossy=*/false, /*limit=*/3, true, &m);
  for (int i = 0; i < 4; ++i) sink.Deliver(Frame(i));
  UpdatePtr u;
  absl::Status final;
  EXPECT_FALSE(sink.Next(&u, &final));
  EXPECT_EQ(final.code(), absl::StatusCode::kResourceExhausted);
}

}  // namespace
}  // namespace dance::server
