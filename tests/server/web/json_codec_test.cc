// The web transport's encoding (server/web/json_codec.h): the browser's JSON decoded straight into the
// core's request types, and core updates encoded as the documented text messages (docs/protocol.md).
#include <memory>
#include <string>
#include <vector>

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
  const UpdatePtr beat = std::make_shared<const Update>(EventUpdate{EventKind::kBeat, 1500.25, 45, ""});
  EXPECT_EQ(UpdateToJson(*beat, true, 0, &scratch), R"({"time_ms":1500.25,"type":"beat"})");
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

TEST(JsonCodec, ControlsInTheDocumentedForm) {
  const nlohmann::json j = nlohmann::json::parse(R"({
    "seed": {"file": "HIERARCHY ...", "start_ms": 500},
    "keyframes": {"positions": [0.5, 1, 2], "times_ms": [1000, 3000]},
    "inpaint_known": [{"start_ms": 0, "end_ms": 4000, "joints": ["upper", "head"]}],
    "trajectory": [{"t_ms": 500, "x": 0.0, "z": 0.0}, {"t_ms": 2500, "x": 1.5, "z": -0.5, "facing": 1.57}]})");
  absl::StatusOr<ControlSpec> c = ControlsFromJson(j);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(c->seed.file, "HIERARCHY ...");
  EXPECT_DOUBLE_EQ(c->seed.start_s, 0.5);
  EXPECT_EQ(c->keyframes.positions, (std::vector<float>{0.5f, 1.0f, 2.0f}));
  EXPECT_EQ(c->keyframes.times_s, (std::vector<double>{1.0, 3.0}));
  EXPECT_TRUE(c->given_upper.empty());
  EXPECT_TRUE(c->inpaint.empty());
  ASSERT_EQ(c->inpaint_known.size(), 1u);
  EXPECT_DOUBLE_EQ(c->inpaint_known[0].end_s, 4.0);
  EXPECT_EQ(c->inpaint_known[0].joints, (std::vector<std::string>{"upper", "head"}));
  ASSERT_EQ(c->trajectory.size(), 2u);
  EXPECT_DOUBLE_EQ(c->trajectory[1].t_s, 2.5);
  EXPECT_FLOAT_EQ(c->trajectory[1].x, 1.5f);
  EXPECT_FLOAT_EQ(c->trajectory[1].z, -0.5f);
  EXPECT_FALSE(c->trajectory[0].facing.has_value());
  ASSERT_TRUE(c->trajectory[1].facing.has_value());
  EXPECT_FLOAT_EQ(*c->trajectory[1].facing, 1.57f);
  absl::StatusOr<ControlSpec> none = ControlsFromJson(nlohmann::json::object());
  ASSERT_TRUE(none.ok());
  EXPECT_TRUE(none->empty());
}

TEST(JsonCodec, BadControlsNameTheKey) {
  const auto error = [](const char* text) {
    absl::StatusOr<ControlSpec> c = ControlsFromJson(nlohmann::json::parse(text));
    EXPECT_EQ(c.status().code(), absl::StatusCode::kInvalidArgument) << text;
    return std::string(c.status().message());
  };
  EXPECT_EQ(error("[]"), "controls must be an object");
  EXPECT_EQ(error(R"({"seed": 3})"), "controls.seed must be an object");
  EXPECT_EQ(error(R"({"given_upper": {"positions": [1, "x"]}})"), "controls.given_upper.positions must be a list of numbers");
  EXPECT_EQ(error(R"({"keyframes": {"file": 7}})"), "controls.keyframes.file must be the file's text");
  EXPECT_EQ(error(R"({"trajectory": [{"t_ms": 0, "x": 1}]})"), "controls.trajectory point needs t_ms, x and z");
  EXPECT_EQ(error(R"({"inpaint_known": [{"start_ms": 0}]})"),
            "controls.inpaint_known entries need start_ms, end_ms and joints");
  EXPECT_EQ(error(R"({"inpaint_known": [{"start_ms": 0, "end_ms": 1, "joints": [3]}]})"),
            "controls.inpaint_known: joints are names");
}

TEST(JsonCodec, SteerPointOrVelocity) {
  absl::StatusOr<SteerTarget> p =
      SteerFromJson(nlohmann::json::parse(R"({"point": {"t_ms": 9000, "x": 0.6, "z": 2.0}})"));
  ASSERT_TRUE(p.ok()) << p.status();
  EXPECT_EQ(p->kind, SteerTarget::Kind::kPoint);
  EXPECT_DOUBLE_EQ(p->t_s, 9.0);
  EXPECT_FLOAT_EQ(p->z, 2.0f);
  absl::StatusOr<SteerTarget> v =
      SteerFromJson(nlohmann::json::parse(R"({"velocity": {"x": 0.3, "z": 0, "facing": 1.5, "hold_ms": 2500}})"));
  ASSERT_TRUE(v.ok()) << v.status();
  EXPECT_EQ(v->kind, SteerTarget::Kind::kVelocity);
  EXPECT_FLOAT_EQ(v->x, 0.3f);
  EXPECT_DOUBLE_EQ(v->hold_s, 2.5);
  ASSERT_TRUE(v->facing.has_value());
  absl::StatusOr<SteerTarget> held = SteerFromJson(nlohmann::json::parse(R"({"velocity": {"x": 0, "z": 0}})"));
  ASSERT_TRUE(held.ok());
  EXPECT_DOUBLE_EQ(held->hold_s, 1.0);  // hold_ms absent: one second
  EXPECT_EQ(SteerFromJson(nlohmann::json::parse(R"({"velocity": 3})")).status().message(),
            "steer needs a point {t_ms, x, z} or a velocity {x, z}");
  EXPECT_EQ(SteerFromJson(nlohmann::json::parse(R"({"point": {"x": 1}})")).status().message(),
            "steer.point needs t_ms, x and z");
}

TEST(JsonCodec, PosesInTheDocumentedForm) {
  nlohmann::json j = {{"type", "poses"}, {"poses", nlohmann::json::array()}};
  std::vector<float> positions(72);
  for (size_t i = 0; i < positions.size(); ++i) positions[i] = 0.01f * static_cast<float>(i);
  j["poses"].push_back({{"time_ms", 1000}, {"positions", positions}, {"part", "upper"}});
  j["poses"].push_back({{"time_ms", 1033.3}, {"positions", positions}, {"part", "lower"}});
  j["poses"].push_back({{"time_ms", 1066.7}, {"positions", positions}, {"part", "all"}});
  j["poses"].push_back({{"time_ms", 1100}, {"positions", positions}, {"part", "legs"}});
  absl::StatusOr<std::vector<PoseRequest>> p = PosesFromJson(j);
  ASSERT_TRUE(p.ok()) << p.status();
  ASSERT_EQ(p->size(), 4u);
  EXPECT_DOUBLE_EQ((*p)[0].time_ms, 1000.0);
  EXPECT_EQ((*p)[0].positions, positions);
  EXPECT_EQ((*p)[0].part, BodyPart::kUpper);
  EXPECT_EQ((*p)[1].part, BodyPart::kLower);
  EXPECT_EQ((*p)[2].part, BodyPart::kAll);
  EXPECT_EQ((*p)[3].part, BodyPart::kUnspecified);  // left to ValidatePose, which names it
  EXPECT_EQ(PosesFromJson(nlohmann::json::parse(R"({"type": "poses"})")).status().message(), "poses must be a list");
  EXPECT_EQ(PosesFromJson(nlohmann::json::parse(R"({"poses": [{"time_ms": 0, "positions": [null]}]})")).status().message(),
            "poses: positions must be numbers");
}

}  // namespace
}  // namespace dance::server
