// The gRPC transport's encoding (server/grpc/convert.h): StreamHeader validation (the core's rules reached
// through the proto), and core updates to DanceUpdate messages.
#include <memory>

#include "absl/strings/match.h"
#include "dance/v1/dance.pb.h"
#include "gtest/gtest.h"
#include "server/core/stream_request.h"
#include "server/core/update.h"
#include "server/grpc/convert.h"

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


UpdatePtr FrameAt(int64_t index) {
  FrameUpdate f;
  f.pose.index = index;
  f.pose.time_s = 0.5;
  f.pose.positions.fill(0.25f);
  f.pose.rotations.fill(1.0f);
  f.pose.upper_code = 3;
  f.pose.lower_code = 7;
  f.trigger_sample_end = 9600;
  f.server_time_us = 123456789;
  return std::make_shared<const Update>(f);
}

TEST(Convert, UpdatesBecomeProtosOncePerForm) {
  const UpdatePtr u = FrameAt(4);
  const dance::v1::DanceUpdate& full = UpdateToProto(*u, /*with_rotations=*/true);
  const dance::v1::DanceUpdate& bare = UpdateToProto(*u, /*with_rotations=*/false);
  ASSERT_TRUE(full.has_frame());
  EXPECT_EQ(full.frame().index(), 4);
  EXPECT_EQ(full.frame().time_ms(), 500.0);
  EXPECT_EQ(full.frame().positions_size(), 72);
  EXPECT_EQ(full.frame().rotations_size(), 96);
  EXPECT_EQ(full.frame().upper_code(), 3);
  EXPECT_EQ(full.frame().lower_code(), 7);
  EXPECT_EQ(full.frame().trigger_sample_end(), 9600);
  EXPECT_EQ(full.frame().server_time_us(), 123456789);
  EXPECT_EQ(bare.frame().rotations_size(), 0);  // omit_rotations
  dance::v1::DanceUpdate stripped = full;
  stripped.mutable_frame()->clear_rotations();
  EXPECT_EQ(bare.SerializeAsString(), stripped.SerializeAsString());
  // Memoised: every call (every gRPC call sending this update) gets the same message.
  EXPECT_EQ(&UpdateToProto(*u, true), &full);
  EXPECT_EQ(&UpdateToProto(*u, false), &bare);
  // Kinds without rotations have one form.
  ModelDescription m = Model();
  m.model_id = "tiny";
  m.joint_names = {"pelvis"};
  m.parents = {-1};
  m.rest_offsets = {0.0f, 0.1f, 0.0f};
  m.samples_per_step = 3200;
  m.frames_per_step = 4;
  const UpdatePtr info = std::make_shared<const Update>(InfoUpdate{"s-1", m});
  EXPECT_EQ(&UpdateToProto(*info, true), &UpdateToProto(*info, false));
  const dance::v1::SessionInfo& si = UpdateToProto(*info, false).info();
  EXPECT_EQ(si.session_id(), "s-1");
  EXPECT_EQ(si.model_id(), "tiny");
  EXPECT_EQ(si.skeleton().rest_offsets_size(), 3);
  EXPECT_EQ(si.styles_size(), 2);
  EXPECT_EQ(si.samples_per_step(), 3200);
  EXPECT_EQ(si.frames_per_step(), 4);
  const UpdatePtr event =
      std::make_shared<const Update>(EventUpdate{EventKind::kControlApplied, 1200.0, 32, "control applied"});
  EXPECT_EQ(UpdateToProto(*event, false).event().kind(), dance::v1::Event::KIND_CONTROL_APPLIED);
  EXPECT_EQ(UpdateToProto(*event, false).event().frame_index(), 32);
  const UpdatePtr end = std::make_shared<const Update>(EndUpdate{180, 6000.0, "end_of_audio"});
  EXPECT_EQ(UpdateToProto(*end, true).end().frames(), 180);
  EXPECT_EQ(UpdateToProto(*end, true).end().reason(), "end_of_audio");
}

}  // namespace
}  // namespace dance::server
