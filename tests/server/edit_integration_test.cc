// Integration: the Edit RPC (docs/diffusion.md, docs/protocol.md) through a real dance-server on port 0
// with the diffusion editor loaded (models/sgmd-tiny.dncw: random weights, 8-frame windows, so a whole
// song takes milliseconds), real gRPC channels and real WAV bytes: the queue/progress/result sequence,
// determinism by seed, a keyframe kept exactly, the errors of bad requests, the per-client limit, and a
// cancelled edit freeing its worker.
#include <cmath>
#include <cstring>
#include <functional>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/synchronization/notification.h"
#include "absl/time/clock.h"
#include "gtest/gtest.h"
#include "server/core/editor_port.h"
#include "tests/server/testing/server_harness.h"

namespace dance::server::testing {
namespace {

constexpr char kEditor[] = "models/sgmd-tiny.dncw";
constexpr int kRate = 24000;

// 16-bit mono PCM WAV bytes.
std::string WavBytes(const std::vector<float>& mono, int rate) {
  std::string out;
  auto u32 = [&out](uint32_t v) { out.append(reinterpret_cast<const char*>(&v), 4); };
  auto u16 = [&out](uint16_t v) { out.append(reinterpret_cast<const char*>(&v), 2); };
  const uint32_t data = static_cast<uint32_t>(mono.size() * 2);
  out += "RIFF";
  u32(36 + data);
  out += "WAVEfmt ";
  u32(16);
  u16(1);
  u16(1);
  u32(static_cast<uint32_t>(rate));
  u32(static_cast<uint32_t>(rate * 2));
  u16(2);
  u16(16);
  out += "data";
  u32(data);
  for (float x : mono) u16(static_cast<uint16_t>(static_cast<int16_t>(std::lround(std::clamp(x, -1.0f, 1.0f) * 32767))));
  return out;
}

struct EditCall {
  grpc::Status status;
  std::vector<dance::v1::EditQueued> queued;
  std::vector<dance::v1::EditProgress> progress;
  dance::v1::EditResult result;
  bool got_result = false;
};

// `on_update`, if set, sees every update as it arrives (on the calling thread).
EditCall RunEdit(dance::v1::DanceService::Stub* stub, const dance::v1::EditRequest& req,
                 grpc::ClientContext* ctx = nullptr,
                 const std::function<void(const dance::v1::EditUpdate&)>& on_update = nullptr) {
  grpc::ClientContext own;
  if (ctx == nullptr) ctx = &own;
  EditCall out;
  auto reader = stub->Edit(ctx, req);
  dance::v1::EditUpdate u;
  while (reader->Read(&u)) {
    if (on_update) on_update(u);
    if (u.has_queued()) out.queued.push_back(u.queued());
    if (u.has_progress()) out.progress.push_back(u.progress());
    if (u.has_result()) {
      out.result = u.result();
      out.got_result = true;
    }
  }
  out.status = reader->Finish();
  return out;
}

class EditTest : public ::testing::Test {
 protected:
  static void Configure(DanceServerOptions& o) {
    absl::StatusOr<std::unique_ptr<EditorBackend>> editor = LoadEditorBackend(kEditor);
    ASSERT_TRUE(editor.ok()) << editor.status();
    o.editor = *std::move(editor);
    o.edit.workers = 1;
    o.edit.max_queued = 4;
    o.edit.max_per_client = 1;
    o.edit.max_audio_s = 120;
  }
  EditTest() : harness_([](DanceServerOptions& o) { Configure(o); }), stub_(harness_.NewStub()) {}

  dance::v1::EditRequest Request(double seconds, uint64_t seed = 1, int steps = 4) const {
    dance::v1::EditRequest r;
    r.set_audio(WavBytes(TestSignal(seconds, kRate), kRate));
    r.set_audio_name("clicks.wav");
    r.set_seed(seed);
    r.set_steps(steps);
    return r;
  }

  ServerHarness harness_;
  std::unique_ptr<dance::v1::DanceService::Stub> stub_;
};

TEST_F(EditTest, StreamsQueueProgressAndTheWholeDance) {
  const EditCall c = RunEdit(stub_.get(), Request(3.0));
  ASSERT_TRUE(c.status.ok()) << c.status.error_message();
  ASSERT_FALSE(c.queued.empty());
  EXPECT_EQ(c.queued.front().position(), 0);
  ASSERT_FALSE(c.progress.empty());
  EXPECT_EQ(c.progress.back().steps_done(), c.progress.back().steps_total());
  ASSERT_TRUE(c.got_result);
  const dance::v1::EditResult& r = c.result;
  EXPECT_EQ(r.model_id(), "sgmd-tiny");
  EXPECT_EQ(r.steps(), 4);
  EXPECT_EQ(c.progress.back().steps_total(), int64_t{r.windows()} * r.steps());
  EXPECT_EQ(r.frames_size(), 90);  // every 30 fps frame of 3 s
  EXPECT_EQ(r.skeleton().joint_names_size(), 24);
  EXPECT_NEAR(r.audio_ms(), 3000.0, 1.0);
  for (int i = 0; i < r.frames_size(); ++i) {
    const dance::v1::PoseFrame& f = r.frames(i);
    ASSERT_EQ(f.index(), i);
    EXPECT_NEAR(f.time_ms(), i * 1000.0 / 30.0, 1e-6);
    ASSERT_EQ(f.positions_size(), 72);
    ASSERT_EQ(f.rotations_size(), 96);
    for (float v : f.positions()) ASSERT_TRUE(std::isfinite(v));
    EXPECT_EQ(f.upper_code(), -1);
  }
}

TEST_F(EditTest, SameSeedSameDanceOtherSeedAnother) {
  const EditCall a = RunEdit(stub_.get(), Request(2.0, 5));
  const EditCall b = RunEdit(stub_.get(), Request(2.0, 5));
  const EditCall c = RunEdit(stub_.get(), Request(2.0, 6));
  ASSERT_TRUE(a.got_result && b.got_result && c.got_result);
  ASSERT_EQ(a.result.frames_size(), b.result.frames_size());
  double same = 0.0, other = 0.0;
  for (int i = 0; i < a.result.frames_size(); ++i) {
    for (int k = 0; k < 72; ++k) {
      same = std::max(same, std::abs(double{a.result.frames(i).positions(k)} - b.result.frames(i).positions(k)));
      other = std::max(other, std::abs(double{a.result.frames(i).positions(k)} - c.result.frames(i).positions(k)));
    }
  }
  EXPECT_EQ(same, 0.0);
  EXPECT_GT(other, 1e-3);
}

TEST_F(EditTest, KeepsAKeyframeExactly) {
  dance::v1::EditRequest req = Request(3.0);
  // A standing pose 1 m along +X at t = 1 s.
  const EditCall free = RunEdit(stub_.get(), req);
  ASSERT_TRUE(free.got_result);
  std::vector<float> pose(free.result.frames(10).positions().begin(), free.result.frames(10).positions().end());
  for (int j = 0; j < 24; ++j) pose[3 * j] += 1.0f;
  dance::v1::Motion* key = req.mutable_controls()->mutable_keyframes();
  for (float v : pose) key->add_positions(v);
  key->add_times_ms(1000.0);
  const EditCall c = RunEdit(stub_.get(), req);
  ASSERT_TRUE(c.status.ok()) << c.status.error_message();
  const dance::v1::PoseFrame& f = c.result.frames(30);
  double worst = 0.0;
  for (int k = 0; k < 72; ++k) worst = std::max(worst, std::abs(double{f.positions(k)} - pose[k]));
  EXPECT_LT(worst, 1e-4) << "the keyframe's joints moved by " << worst << " m";
}

TEST_F(EditTest, BadRequestsAreInvalidArgumentNamingTheField) {
  struct Case {
    std::string name, want;
    std::function<void(dance::v1::EditRequest&)> change;
  };
  const std::vector<Case> cases = {
      {"no audio", "audio", [](dance::v1::EditRequest& r) { r.clear_audio(); }},
      {"not audio", "audio", [](dance::v1::EditRequest& r) { r.set_audio(std::string(1000, 'x')); }},
      {"steps", "steps", [](dance::v1::EditRequest& r) { r.set_steps(5000); }},
      {"guidance", "guidance", [](dance::v1::EditRequest& r) { r.set_guidance(-1.0f); }},
      {"overlap", "overlap_s", [](dance::v1::EditRequest& r) { r.set_overlap_s(9.0f); }},
      {"style", "style", [](dance::v1::EditRequest& r) {
         dance::v1::StyleWeight* w = r.add_style();
         w->set_name("polka");
         w->set_weight(1.0f);
       }},
      {"keyframe shape", "keyframes", [](dance::v1::EditRequest& r) {
         r.mutable_controls()->mutable_keyframes()->add_positions(1.0f);
       }},
  };
  for (const Case& c : cases) {
    dance::v1::EditRequest r = Request(1.0);
    c.change(r);
    const EditCall call = RunEdit(stub_.get(), r);
    EXPECT_EQ(call.status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << c.name << ": "
                                                                           << call.status.error_message();
    EXPECT_NE(call.status.error_message().find(c.want), std::string::npos) << c.name << ": "
                                                                           << call.status.error_message();
    EXPECT_FALSE(call.got_result) << c.name;
  }
}

TEST_F(EditTest, ModelInfoDescribesTheEditor) {
  grpc::ClientContext ctx;
  dance::v1::ModelInfo info;
  ASSERT_TRUE(stub_->GetModelInfo(&ctx, dance::v1::GetModelInfoRequest(), &info).ok());
  ASSERT_TRUE(info.has_editor());
  EXPECT_EQ(info.editor().model_id(), "sgmd-tiny");
  EXPECT_EQ(info.editor().workers(), 1);
  EXPECT_EQ(info.editor().max_per_client(), 1);
  EXPECT_GT(info.editor().default_steps(), 0);
  EXPECT_GE(info.editor().styles_size(), 1);
}

TEST_F(EditTest, OneClientOneEditAndACancelledEditFreesItsWorker) {
  // A long edit: 60 s of music at 1000 steps (tens of seconds with the tiny model).
  grpc::ClientContext long_ctx;
  dance::v1::EditRequest long_req = Request(60.0, 1, 1000);
  EditCall long_call;
  absl::Notification accepted;  // the long edit is queued or running (its first update came)
  std::thread runner([&] {
    long_call = RunEdit(stub_.get(), long_req, &long_ctx, [&accepted](const dance::v1::EditUpdate&) {
      if (!accepted.HasBeenNotified()) accepted.Notify();
    });
    if (!accepted.HasBeenNotified()) accepted.Notify();  // it failed: the assertions below say how
  });
  ASSERT_TRUE(accepted.WaitForNotificationWithTimeout(absl::Seconds(60)));
  const grpc::Status second = RunEdit(stub_.get(), Request(1.0)).status;
  EXPECT_EQ(second.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << second.error_message();
  EXPECT_NE(second.error_message().find("already has"), std::string::npos) << second.error_message();
  long_ctx.TryCancel();
  runner.join();
  EXPECT_EQ(long_call.status.error_code(), grpc::StatusCode::CANCELLED) << long_call.status.error_message();
  EXPECT_FALSE(long_call.got_result);
  if (!long_call.progress.empty()) {
    EXPECT_LT(long_call.progress.back().steps_done(), long_call.progress.back().steps_total());
  }
  // The worker is free again: a new edit from the same client runs to its result.
  EditCall after;
  for (int i = 0; i < 500; ++i) {
    after = RunEdit(stub_.get(), Request(1.0));
    if (after.status.error_code() != grpc::StatusCode::RESOURCE_EXHAUSTED) break;
    absl::SleepFor(absl::Milliseconds(20));
  }
  ASSERT_TRUE(after.status.ok()) << after.status.error_message();
  EXPECT_TRUE(after.got_result);
}

TEST(EditWithoutEditor, IsUnimplemented) {
  ServerHarness h;
  auto stub = h.NewStub();
  dance::v1::EditRequest r;
  r.set_audio(WavBytes(TestSignal(1.0, kRate), kRate));
  const EditCall c = RunEdit(stub.get(), r);
  EXPECT_EQ(c.status.error_code(), grpc::StatusCode::UNIMPLEMENTED) << c.status.error_message();
}

}  // namespace
}  // namespace dance::server::testing
