// Integration: a real dance-server (real engine, tiny model) on port 0, real gRPC channels.
#include <atomic>
#include <cmath>
#include <functional>
#include <map>
#include <string>
#include <thread>
#include <vector>

#include "absl/synchronization/notification.h"
#include "absl/time/clock.h"
#include "gtest/gtest.h"
#include "tests/engine/runtime/testing/tiny_model.h"
#include "tests/server/testing/server_harness.h"

namespace dance::server::testing {
namespace {

// Opens a stream on `backend`, pushes the first half of `audio` and steps, calls `between` on the stream
// (the Controls under test), pushes the rest, ends the audio, and returns every frame.
std::vector<FrameData> RunInHalves(const EngineBackend& backend, const StreamConfig& config,
                                   const std::vector<float>& audio,
                                   const std::function<void(EngineStream&)>& between) {
  absl::StatusOr<std::unique_ptr<EngineStream>> s = backend.Open(config);
  EXPECT_TRUE(s.ok()) << s.status();
  if (!s.ok()) return {};
  EngineStream* stream = s->get();
  auto drain = [&] {
    while (stream->StepsReady() > 0) EXPECT_TRUE(backend.StepBatch(absl::MakeConstSpan(&stream, 1)).ok());
  };
  const size_t half = audio.size() / 2;
  EXPECT_TRUE(stream->PushAudio(absl::MakeConstSpan(audio.data(), half)).ok());
  drain();
  between(*stream);
  EXPECT_TRUE(stream->PushAudio(absl::MakeConstSpan(audio.data() + half, audio.size() - half)).ok());
  stream->EndOfAudio();
  drain();
  std::vector<FrameData> frames;
  stream->PopFrames(&frames);
  return frames;
}

TEST(PerformIntegration, FullSessionProducesEveryFrameInOrder) {
  ServerHarness h;
  auto stub = h.NewStub();
  const std::vector<float> audio = TestSignal(3.0, 24000);
  PerformResult r = RunPerform(stub.get(), audio, 24000, /*seed=*/7);
  ASSERT_TRUE(r.status.ok()) << r.status.error_message();
  EXPECT_FALSE(r.info.session_id().empty());
  EXPECT_EQ(r.info.fps(), 30.0);
  EXPECT_EQ(r.info.skeleton().joint_names_size(), 24);
  EXPECT_EQ(r.info.skeleton().rest_offsets_size(), 72);
  ASSERT_TRUE(r.got_end);
  EXPECT_EQ(r.end.reason(), "end_of_audio");
  ASSERT_GE(r.frames.size(), 80u);  // 3 s = 90 frames; the first period has no pose
  EXPECT_EQ(static_cast<int64_t>(r.frames.size()), r.end.frames());
  for (size_t i = 1; i < r.frames.size(); ++i) ASSERT_EQ(r.frames[i].index(), r.frames[i - 1].index() + 1);
  for (const auto& f : r.frames) {
    ASSERT_EQ(f.positions_size(), 72);
    ASSERT_EQ(f.rotations_size(), 96);
    EXPECT_NEAR(f.time_ms(), f.index() * 1000.0 / 30.0, 1e-6);
    EXPECT_GT(f.trigger_sample_end(), 0);
  }
  EXPECT_NEAR(r.end.audio_ms(), 3000.0, 1e-6);
}

std::vector<double> BeatMs(const std::vector<dance::v1::Event>& events) {
  std::vector<double> out;
  for (const auto& e : events) {
    if (e.kind() == dance::v1::Event::KIND_BEAT) out.push_back(e.time_ms());
  }
  return out;
}

TEST(PerformIntegration, BeatsArriveAsEventsOnTheClicks) {
  ServerHarness h;
  auto stub = h.NewStub();
  const std::vector<float> audio = TestSignal(10.0, 24000);  // clicks every 500 ms
  PerformResult r = RunPerform(stub.get(), audio, 24000, /*seed=*/3, /*chunk_frames=*/2400);
  ASSERT_TRUE(r.status.ok()) << r.status.error_message();
  const std::vector<double> beats = BeatMs(r.events);
  ASSERT_GE(beats.size(), 12u);
  int late = 0, on_click = 0;
  for (const auto& e : r.events) {
    if (e.kind() != dance::v1::Event::KIND_BEAT) continue;
    EXPECT_EQ(e.frame_index(), std::llround(e.time_ms() * 30.0 / 1000.0));
    if (e.time_ms() < 4000.0) continue;
    ++late;
    on_click += std::abs(e.time_ms() - 500.0 * std::round(e.time_ms() / 500.0)) < 40.0;
  }
  EXPECT_GE(late, 10);  // 6 s of clicks at 2 a second
  EXPECT_GE(on_click, late - 1) << late - on_click << " of " << late << " beats after 4 s off the clicks";
  for (size_t i = 1; i < beats.size(); ++i) ASSERT_GT(beats[i], beats[i - 1]);
  // The same beats however the audio is chunked (the engine's tracker is chunking-invariant).
  PerformResult other = RunPerform(stub.get(), audio, 24000, /*seed=*/3, /*chunk_frames=*/1777);
  ASSERT_TRUE(other.status.ok());
  EXPECT_EQ(BeatMs(other.events), beats);
}

TEST(PerformIntegration, ServerDanceEqualsTheEngineRunDirectly) {
  ServerHarness h;
  auto stub = h.NewStub();
  const std::vector<float> audio = TestSignal(2.5, 44100);
  // Odd chunking on purpose: the engine is chunking-invariant, so the server's batching must be too.
  PerformResult r = RunPerform(stub.get(), audio, 44100, /*seed=*/11, /*chunk_frames=*/1777);
  ASSERT_TRUE(r.status.ok()) << r.status.error_message();
  std::vector<dance::v1::PoseFrame> ref = RunEngineDirect(TinyModelPath(), audio, 44100, 11);
  ASSERT_EQ(r.frames.size(), ref.size());
  for (size_t i = 0; i < ref.size(); ++i) {
    ASSERT_EQ(r.frames[i].index(), ref[i].index());
    ASSERT_EQ(r.frames[i].upper_code(), ref[i].upper_code()) << "frame " << i;
    ASSERT_EQ(r.frames[i].lower_code(), ref[i].lower_code()) << "frame " << i;
    for (int k = 0; k < 72; ++k) ASSERT_EQ(r.frames[i].positions(k), ref[i].positions(k)) << "frame " << i;
  }
}

TEST(EngineBackend, ControlKeepsTheGuidanceTopPAndLockItLeavesUnset) {
  // A Control's sampling with guidance 0, top_p 0 and no period_lock (converted to negative values) keeps
  // the values in effect; in a StreamHeader the same mean the model's defaults (tiny model: guidance 1).
  absl::StatusOr<std::unique_ptr<EngineBackend>> backend = LoadEngineBackend(TinyModelPath());
  ASSERT_TRUE(backend.ok()) << backend.status();
  StreamConfig config;
  config.style = {{"waltz", 1.0f}};  // guidance has no effect with style "none"
  config.seed = 4;
  config.sampling.guidance = 2.5f;
  config.sampling.top_p = 0.8f;
  config.sampling.music_guidance = 0.5f;  // an unset music_guidance in a Control keeps it too
  const std::vector<float> audio = TestSignal(6.0, 24000);
  auto run = [&](const SamplingConfig* control) {
    return RunInHalves(**backend, config, audio, [&](EngineStream& stream) {
      if (control != nullptr) {
        EXPECT_TRUE(stream.SetSampling(*control).ok());
      }
    });
  };
  SamplingConfig keep;  // temperature 1, top_k 0: as opened; the rest unset
  SamplingConfig guidance_off = keep;
  guidance_off.guidance = 1.0f;
  SamplingConfig no_cut = keep;
  no_cut.top_p = 1.0f;
  SamplingConfig music_off = keep;
  music_off.music_guidance = 1.0f;
  const std::vector<FrameData> base = run(nullptr), kept = run(&keep);
  ASSERT_EQ(base.size(), kept.size());
  ASSERT_GT(base.size(), 100u);
  for (size_t i = 0; i < base.size(); ++i) {
    ASSERT_EQ(base[i].upper_code, kept[i].upper_code) << "frame " << i;
    ASSERT_EQ(base[i].lower_code, kept[i].lower_code) << "frame " << i;
  }
  // Setting them does change the continuation (so the comparison above could fail).
  for (const SamplingConfig* changed : {&guidance_off, &no_cut, &music_off}) {
    const std::vector<FrameData> other = run(changed);
    ASSERT_EQ(other.size(), base.size());
    int differ = 0;
    for (size_t i = 0; i < base.size(); ++i) differ += other[i].upper_code != base[i].upper_code;
    EXPECT_GT(differ, 0);
  }
}

TEST(EngineBackend, AnUnsetPeriodLockKeepsFollowingTheStyle) {
  // A model whose waltz is unlocked (time_base.style_period_lock {"waltz": 0}) and whose other styles lock
  // at 6. A Control's sampling without period_lock keeps "the model's default", so a later switch from
  // tango to waltz unlocks the dance exactly as with no sampling Control; pinning the weight in effect
  // (6, tango's) would keep the waltz locked, which the comparisons show is a different dance; and a
  // Control with period_lock -1 takes a stream opened with the pin back to the default.
  engine::testing::TinyModelOptions o;
  o.tempo_reference_bpm = 105.0;
  o.style_reference_bpm = {{"waltz", 90.0}, {"tango", 120.0}};
  o.dance_period_beats = {{"waltz", 3.0}, {"tango", 2.0}};
  o.period_lock = 6.0;
  o.style_period_lock = {{"waltz", 0.0}};
  const std::string path = ::testing::TempDir() + "/style-lock-tiny.dncw";
  ASSERT_TRUE(engine::testing::TinyModelWriter(o).WriteFile(path).ok());
  absl::StatusOr<std::unique_ptr<EngineBackend>> backend = LoadEngineBackend(path);
  ASSERT_TRUE(backend.ok()) << backend.status();
  const ModelDescription& desc = (*backend)->Describe();
  EXPECT_EQ(desc.default_period_lock, 6.0f);
  EXPECT_EQ(desc.style_period_lock, (std::map<std::string, float>{{"waltz", 0.0f}, {"tango", 6.0f}}));
  StreamConfig config;
  config.style = {{"tango", 1.0f}};
  config.seed = 3;
  const std::vector<float> audio = engine::testing::ClickAudio(8.0, 110.0);
  auto run = [&](const StreamConfig& opened, const SamplingConfig* control) {
    return RunInHalves(**backend, opened, audio, [&](EngineStream& stream) {
      if (control != nullptr) {
        EXPECT_TRUE(stream.SetSampling(*control).ok());
      }
      EXPECT_TRUE(stream.SetStyle({{"waltz", 1.0f}}).ok());
    });
  };
  SamplingConfig keep;  // temperature 1, top_k 0: as opened; the rest unset
  SamplingConfig pinned = keep;
  pinned.period_lock = 6.0f;
  SamplingConfig back_to_default = keep;
  back_to_default.period_lock = -1.0f;  // the proto's -1: the model's style-following default again
  StreamConfig opened_pinned = config;  // tango's default is 6 too, so the first halves are the same dance
  opened_pinned.sampling = pinned;
  const std::vector<FrameData> base = run(config, nullptr), kept = run(config, &keep),
                               locked = run(config, &pinned), unpinned = run(opened_pinned, &back_to_default),
                               still_pinned = run(opened_pinned, &keep);
  ASSERT_EQ(base.size(), kept.size());
  ASSERT_EQ(base.size(), locked.size());
  ASSERT_EQ(base.size(), unpinned.size());
  ASSERT_EQ(base.size(), still_pinned.size());
  ASSERT_GT(base.size(), 200u);
  int differ = 0, differ_pinned = 0;
  for (size_t i = 0; i < base.size(); ++i) {
    ASSERT_EQ(base[i].upper_code, kept[i].upper_code) << "frame " << i;
    ASSERT_EQ(base[i].lower_code, kept[i].lower_code) << "frame " << i;
    ASSERT_EQ(base[i].upper_code, unpinned[i].upper_code) << "frame " << i;
    ASSERT_EQ(base[i].lower_code, unpinned[i].lower_code) << "frame " << i;
    differ += base[i].upper_code != locked[i].upper_code || base[i].lower_code != locked[i].lower_code;
    ASSERT_EQ(locked[i].upper_code, still_pinned[i].upper_code) << "frame " << i;
    differ_pinned += base[i].upper_code != still_pinned[i].upper_code;
  }
  EXPECT_GT(differ, 0);
  EXPECT_GT(differ_pinned, 0);  // opened pinned, a Control without period_lock keeps the pin
}

TEST(EngineBackend, RawFeetIsAStreamSettingThatControlsKeep) {
  // The shipped model (its feet plant; the tiny model's random poses may never touch the floor). A stream
  // opened with raw feet stays raw after a sampling Control (which carries no foot setting), and the foot
  // lock, on by default, changes only the legs.
  absl::StatusOr<std::unique_ptr<EngineBackend>> backend = LoadEngineBackend("models/default.dncw");
  ASSERT_TRUE(backend.ok()) << backend.status() << " (run from the source root)";
  const std::vector<float> audio = engine::testing::ClickAudio(16.0, 125.0);
  auto run = [&](bool foot_lock, const SamplingConfig* control) {
    StreamConfig config;
    config.style = {{"rumba", 1.0f}};
    config.seed = 2;
    config.foot_lock = foot_lock;
    return RunInHalves(**backend, config, audio, [&](EngineStream& stream) {
      if (control != nullptr) {
        EXPECT_TRUE(stream.SetSampling(*control).ok());
      }
    });
  };
  SamplingConfig keep;  // temperature 1, top_k 0: as opened; the rest unset
  const std::vector<FrameData> raw = run(false, nullptr), raw_control = run(false, &keep),
                               locked = run(true, &keep);
  ASSERT_EQ(raw.size(), raw_control.size());
  ASSERT_EQ(raw.size(), locked.size());
  ASSERT_GT(raw.size(), 400u);
  int legs_differ_after_control = 0;
  for (size_t i = 0; i < raw.size(); ++i) {
    ASSERT_EQ(raw[i].positions, raw_control[i].positions) << "frame " << i;
    ASSERT_EQ(raw[i].lower_code, locked[i].lower_code) << "frame " << i;
    for (int j = 0; j < kNumJoints; ++j) {
      const bool leg = j == 4 || j == 5 || j == 7 || j == 8 || j == 10 || j == 11;
      for (int k = 0; k < 3; ++k) {
        const float a = raw[i].positions[3 * j + k], b = locked[i].positions[3 * j + k];
        if (!leg) {
          ASSERT_EQ(a, b) << "frame " << i << " joint " << j;
        }
        if (leg && i >= raw.size() / 2 && std::abs(a - b) > 1e-3f) ++legs_differ_after_control;
      }
    }
  }
  EXPECT_GT(legs_differ_after_control, 50);
}

TEST(PerformIntegration, TwentyConcurrentSessionsAllComplete) {
  ServerHarness h;
  const std::vector<float> audio = TestSignal(2.0, 24000);
  std::vector<PerformResult> results(20);
  std::vector<std::thread> threads;
  for (int i = 0; i < 20; ++i) {
    threads.emplace_back([&, i] {
      auto stub = h.NewStub();
      results[i] = RunPerform(stub.get(), audio, 24000, /*seed=*/static_cast<uint64_t>(i % 2), 2400);
    });
  }
  for (auto& t : threads) t.join();
  std::vector<dance::v1::PoseFrame> ref0 = RunEngineDirect(TinyModelPath(), audio, 24000, 0);
  std::vector<dance::v1::PoseFrame> ref1 = RunEngineDirect(TinyModelPath(), audio, 24000, 1);
  for (int i = 0; i < 20; ++i) {
    ASSERT_TRUE(results[i].status.ok()) << i << ": " << results[i].status.error_message();
    const auto& ref = i % 2 == 0 ? ref0 : ref1;
    ASSERT_EQ(results[i].frames.size(), ref.size()) << i;
    // Batched with 19 others, each session still gets its own dance: the same codes, and positions equal
    // up to float rounding (a batched matrix product may round differently from a single one).
    for (size_t f = 0; f < ref.size(); ++f) {
      ASSERT_EQ(results[i].frames[f].upper_code(), ref[f].upper_code()) << i << "/" << f;
      ASSERT_EQ(results[i].frames[f].lower_code(), ref[f].lower_code()) << i << "/" << f;
      for (int k = 0; k < 72; ++k) {
        ASSERT_NEAR(results[i].frames[f].positions(k), ref[f].positions(k), 1e-4) << i << "/" << f;
      }
    }
  }
  EXPECT_EQ(h.server().hub().active_sessions(), 0);
  EXPECT_GT(h.server().metrics().batch_size.count(), 0u);
}

TEST(PerformIntegration, WatcherReceivesTheSameFrames) {
  ServerHarness h([](DanceServerOptions& o) { o.service.viewer_queue_frames = 100000; });
  auto stub = h.NewStub();
  grpc::ClientContext ctx;
  auto stream = stub->Perform(&ctx);
  dance::v1::PerformRequest req;
  req.mutable_header()->set_sample_rate_hz(24000);
  req.mutable_header()->set_channels(1);
  req.mutable_header()->set_sample_format(dance::v1::SAMPLE_FORMAT_F32LE);
  ASSERT_TRUE(stream->Write(req));
  dance::v1::DanceUpdate info;
  ASSERT_TRUE(stream->Read(&info));
  ASSERT_TRUE(info.has_info());
  const std::string id = info.info().session_id();

  // The watcher subscribes before any audio, so it must see every frame the performer sees.
  std::vector<dance::v1::PoseFrame> watched;
  std::vector<dance::v1::Event> watched_events;
  bool watch_info = false, watch_end = false;
  grpc::Status watch_status;
  absl::Notification subscribed;
  std::thread watcher([&] {
    auto wstub = h.NewStub();
    grpc::ClientContext wctx;
    dance::v1::WatchRequest wr;
    wr.set_session_id(id);
    auto reader = wstub->Watch(&wctx, wr);
    dance::v1::DanceUpdate u;
    while (reader->Read(&u)) {
      if (u.has_info()) {
        watch_info = true;
        subscribed.Notify();
      }
      if (u.has_frame()) watched.push_back(u.frame());
      if (u.has_event()) watched_events.push_back(u.event());
      if (u.has_end()) watch_end = true;
    }
    watch_status = reader->Finish();
    if (!subscribed.HasBeenNotified()) subscribed.Notify();
  });
  subscribed.WaitForNotification();
  const std::vector<float> audio = TestSignal(4.0, 24000);
  for (size_t off = 0; off < audio.size(); off += 2400) {
    req.Clear();
    req.mutable_audio()->set_sample_offset(static_cast<int64_t>(off));
    req.mutable_audio()->set_pcm(reinterpret_cast<const char*>(audio.data() + off), 2400 * sizeof(float));
    ASSERT_TRUE(stream->Write(req));
  }
  req.Clear();
  req.mutable_end();
  ASSERT_TRUE(stream->Write(req));
  stream->WritesDone();
  std::vector<dance::v1::PoseFrame> performed;
  std::vector<dance::v1::Event> performed_events;
  dance::v1::DanceUpdate u;
  while (stream->Read(&u)) {
    if (u.has_frame()) performed.push_back(u.frame());
    if (u.has_event()) performed_events.push_back(u.event());
  }
  ASSERT_TRUE(stream->Finish().ok());
  watcher.join();
  EXPECT_TRUE(watch_status.ok()) << watch_status.error_message();
  EXPECT_TRUE(watch_info);
  EXPECT_TRUE(watch_end);
  ASSERT_EQ(watched.size(), performed.size());
  for (size_t i = 0; i < performed.size(); ++i) {
    EXPECT_EQ(watched[i].index(), performed[i].index());
    EXPECT_EQ(watched[i].upper_code(), performed[i].upper_code());
    EXPECT_EQ(watched[i].positions(5), performed[i].positions(5));
    EXPECT_EQ(watched[i].dropped_before(), 0);
  }
  // Viewers get the beats too (a watching page pulses on them).
  EXPECT_FALSE(BeatMs(performed_events).empty());
  EXPECT_EQ(BeatMs(watched_events), BeatMs(performed_events));
}

TEST(PerformIntegration, ListSessionsAndModelInfo) {
  ServerHarness h([](DanceServerOptions& o) { o.hub.max_sessions = 5; });
  auto stub = h.NewStub();
  grpc::ClientContext ctx;
  dance::v1::ModelInfo mi;
  ASSERT_TRUE(stub->GetModelInfo(&ctx, {}, &mi).ok());
  EXPECT_EQ(mi.max_sessions(), 5);
  EXPECT_EQ(mi.skeleton().parents_size(), 24);
  EXPECT_EQ(mi.skeleton().parents(0), -1);
  // Every style of the model has its period lock listed (the tiny model has no per-style weights: the
  // default's).
  ASSERT_GT(mi.styles_size(), 0);
  EXPECT_EQ(mi.style_period_lock_size(), mi.styles_size());
  for (const std::string& style : mi.styles()) {
    ASSERT_EQ(mi.style_period_lock().count(style), 1u) << style;
    EXPECT_EQ(mi.style_period_lock().at(style), mi.default_period_lock()) << style;
  }

  grpc::ClientContext pctx;
  auto stream = stub->Perform(&pctx);
  dance::v1::PerformRequest req;
  req.mutable_header()->set_sample_rate_hz(16000);
  req.mutable_header()->set_channels(2);
  req.mutable_header()->set_sample_format(dance::v1::SAMPLE_FORMAT_S16LE);
  req.mutable_header()->set_client_name("lister");
  ASSERT_TRUE(stream->Write(req));
  dance::v1::DanceUpdate info;
  ASSERT_TRUE(stream->Read(&info));
  grpc::ClientContext lctx;
  dance::v1::ListSessionsResponse list;
  ASSERT_TRUE(stub->ListSessions(&lctx, {}, &list).ok());
  ASSERT_EQ(list.sessions_size(), 1);
  EXPECT_EQ(list.sessions(0).session_id(), info.info().session_id());
  EXPECT_EQ(list.sessions(0).client_name(), "lister");
  pctx.TryCancel();
  stream->Finish();
}

}  // namespace
}  // namespace dance::server::testing
