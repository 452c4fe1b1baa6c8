// The web transport's encoding (server/web/json_codec.h): the browser's JSON decoded straight into the
// core's request types, and core updates encoded as the documented text messages (docs/protocol.md).
#include <memory>
#include <string>

#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "server/core/update.h"
#include "server/web/json_codec.h"

namespace dance::server {
namespace {

ModelDescription Model() {
  ModelDescription m;
  m.styles = {"breaking", "popping"};
  return m;
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

// The browser's start message reaches the core's validation directly: its errors name the field.
TEST(JsonCodec, StartIsValidatedByTheCoreRules) {
  auto r = StreamRequestFromJson(nlohmann::json::parse(R"({"type":"start","sample_rate":48000,"style":"waltz"})"));
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(r->format, PcmFormat::kF32Le);
  EXPECT_EQ(r->channels, 1);
  auto v = ValidateStream(*r, Model(), {});
  ASSERT_FALSE(v.ok());
  EXPECT_EQ(v.status().message(), "unknown style 'waltz'");
  r = StreamRequestFromJson(nlohmann::json::parse(R"({"type":"start","sample_rate":48000,"top_p":0})"));
  ASSERT_TRUE(r.ok());
  v = ValidateStream(*r, Model(), {});
  ASSERT_TRUE(v.ok()) << v.status();
  EXPECT_LT(v->config.sampling.top_p, 0.0f);  // 0: the model's default
  EXPECT_FALSE(v->omit_rotations);
  auto bad_style = StreamRequestFromJson(nlohmann::json::parse(R"({"type":"start","style":[{"weight":1}]})"));
  EXPECT_EQ(bad_style.status().message(), "style entries need a string 'name'");
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

// The exact text (docs/protocol.md section 3): keys sorted, no spaces, rotations [] when omitted.
TEST(JsonCodec, FrameTextIsByteExactAndSharedPerForm) {
  const UpdatePtr u = Frame(4, 0.13325);
  std::string positions;
  for (int i = 0; i < 72; ++i) positions += i == 0 ? "0.5" : ",0.5";
  std::string scratch;
  const absl::string_view bare = UpdateToJson(*u, /*with_rotations=*/false, 0, &scratch);
  EXPECT_EQ(bare, R"({"dropped_before":0,"index":4,"lower_code":7,"positions":[)" + positions +
                      R"(],"rotations":[],"time_ms":133.25,"type":"frame","upper_code":3})");
  EXPECT_TRUE(scratch.empty());
  // Memoised: every socket sending this update gets the same text.
  EXPECT_EQ(UpdateToJson(*u, false, 0, &scratch).data(), bare.data());
  const absl::string_view full = UpdateToJson(*u, true, 0, &scratch);
  EXPECT_NE(full.data(), bare.data());
  EXPECT_EQ(nlohmann::json::parse(full)["rotations"].size(), 96u);
  // A viewer's dropped_before is its own: written into its scratch, the shared text untouched.
  const absl::string_view dropped = UpdateToJson(*u, false, 5, &scratch);
  EXPECT_EQ(dropped.data(), scratch.data());
  EXPECT_EQ(dropped.substr(0, 26), R"({"dropped_before":5,"index)");
  EXPECT_EQ(UpdateToJson(*u, false, 0, &scratch), bare);
}

TEST(JsonCodec, OtherUpdatesAsDocumented) {
  std::string scratch;
  const UpdatePtr event =
      std::make_shared<const Update>(EventUpdate{EventKind::kControlApplied, 1200.0, 32, "control applied"});
  EXPECT_EQ(UpdateToJson(*event, false, 0, &scratch),
            R"({"frame_index":32,"kind":"control_applied","message":"control applied","time_ms":1200.0,"type":"event"})");
  const UpdatePtr warning = std::make_shared<const Update>(EventUpdate{EventKind::kWarning, 0.0, 0, "w"});
  EXPECT_EQ(UpdateToJson(*warning, true, 0, &scratch),
            R"({"frame_index":0,"kind":"warning","message":"w","time_ms":0.0,"type":"event"})");
  const UpdatePtr end = std::make_shared<const Update>(EndUpdate{180, 6000.0, "end_of_audio"});
  EXPECT_EQ(UpdateToJson(*end, true, 0, &scratch),
            R"({"audio_ms":6000.0,"frames":180,"reason":"end_of_audio","type":"end"})");
  EXPECT_EQ(UpdateToJson(*end, true, 0, &scratch).data(), UpdateToJson(*end, false, 0, &scratch).data());
  ModelDescription m = Model();
  m.model_id = "tiny";
  m.joint_names = {"pelvis"};
  m.parents = {-1};
  m.rest_offsets = {0.0f, 0.5f, 0.0f};
  m.latency_ms = 0.0;
  const UpdatePtr info = std::make_shared<const Update>(InfoUpdate{"s-1", m});
  EXPECT_EQ(UpdateToJson(*info, false, 0, &scratch),
            R"({"fps":30.0,"joint_names":["pelvis"],"latency_ms":0.0,"model_id":"tiny","parents":[-1],)"
            R"("rest_offsets":[0.0,0.5,0.0],"session_id":"s-1","styles":["breaking","popping"],"type":"info"})");
  EXPECT_EQ(ErrorToJson(absl::InvalidArgumentError("bad")),
            R"({"code":"INVALID_ARGUMENT","message":"bad","type":"error"})");
}

}  // namespace
}  // namespace dance::server
