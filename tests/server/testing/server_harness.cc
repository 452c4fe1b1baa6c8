#include "tests/server/testing/server_harness.h"

#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <filesystem>

#include "absl/strings/str_cat.h"
#include "engine/runtime/session.h"
#include "gtest/gtest.h"
#include "server/core/engine_port.h"
#include "server/log.h"
#include "tests/engine/runtime/testing/tiny_model.h"

namespace dance::server::testing {

std::string TinyModelPath() {
  const char* src = std::getenv("DANCE_SOURCE_DIR");
  const std::string committed = absl::StrCat(src ? src : ".", "/models/test-tiny.dncw");
  static const bool committed_loads = [&committed] {
    if (!std::filesystem::exists(committed)) return false;
    auto m = engine::LoadModel(committed);
    if (!m.ok()) std::fprintf(stderr, "note: %s does not load (%s); using the C++ tiny model\n",
                              committed.c_str(), m.status().ToString().c_str());
    return m.ok();
  }();
  if (committed_loads) return committed;
  static const std::string path = [] {
    const std::string p = absl::StrCat(::testing::TempDir(), "/server-tiny-", getpid(), ".dncw");
    engine::testing::TinyModelOptions opt;
    absl::Status s = engine::testing::TinyModelWriter(opt).WriteFile(p);
    if (!s.ok()) {
      std::fprintf(stderr, "cannot write tiny model: %s\n", s.ToString().c_str());
      std::abort();
    }
    return p;
  }();
  return path;
}

ServerHarness::ServerHarness(std::function<void(DanceServerOptions&)> configure, const std::string& model_path) {
  SetLogLevel(LogLevel::kWarning);
  DanceServerOptions o;
  o.host = "127.0.0.1";
  o.port = 0;
  o.http_port = 0;
  o.web.web_root = "";
  if (configure) configure(o);
  absl::StatusOr<std::unique_ptr<EngineBackend>> backend = LoadEngineBackend(model_path.empty() ? TinyModelPath() : model_path);
  if (!backend.ok()) {
    ADD_FAILURE() << backend.status();
    std::abort();
  }
  absl::StatusOr<std::unique_ptr<DanceServer>> s = DanceServer::Start(*std::move(backend), o);
  if (!s.ok()) {
    ADD_FAILURE() << s.status();
    std::abort();
  }
  server_ = *std::move(s);
}

ServerHarness::~ServerHarness() { server_->Shutdown(); }

std::string ServerHarness::target() const { return absl::StrCat("127.0.0.1:", server_->port()); }

std::shared_ptr<grpc::Channel> ServerHarness::NewChannel() const {
  grpc::ChannelArguments args;
  args.SetInt(GRPC_ARG_USE_LOCAL_SUBCHANNEL_POOL, 1);
  return grpc::CreateCustomChannel(target(), grpc::InsecureChannelCredentials(), args);
}

std::unique_ptr<dance::v1::DanceService::Stub> ServerHarness::NewStub() const {
  return dance::v1::DanceService::NewStub(NewChannel());
}

PerformResult RunPerform(dance::v1::DanceService::Stub* stub, const std::vector<float>& audio, int sample_rate,
                         uint64_t seed, int chunk_frames, float temperature) {
  PerformResult r;
  grpc::ClientContext ctx;
  auto stream = stub->Perform(&ctx);
  dance::v1::PerformRequest req;
  dance::v1::StreamHeader* h = req.mutable_header();
  h->set_sample_rate_hz(sample_rate);
  h->set_channels(1);
  h->set_sample_format(dance::v1::SAMPLE_FORMAT_F32LE);
  h->set_seed(seed);
  h->mutable_sampling()->set_temperature(temperature);
  bool ok = stream->Write(req);
  for (size_t off = 0; ok && off < audio.size(); off += chunk_frames) {
    const size_t n = std::min<size_t>(chunk_frames, audio.size() - off);
    req.Clear();
    req.mutable_audio()->set_sample_offset(static_cast<int64_t>(off));
    req.mutable_audio()->set_pcm(reinterpret_cast<const char*>(audio.data() + off), n * sizeof(float));
    ok = stream->Write(req);
  }
  if (ok) {
    req.Clear();
    req.mutable_end();
    stream->Write(req);
  }
  stream->WritesDone();
  dance::v1::DanceUpdate u;
  while (stream->Read(&u)) {
    if (u.has_info()) r.info = u.info();
    if (u.has_frame()) r.frames.push_back(u.frame());
    if (u.has_event()) r.events.push_back(u.event());
    if (u.has_end()) {
      r.end = u.end();
      r.got_end = true;
    }
  }
  r.status = stream->Finish();
  return r;
}

std::vector<dance::v1::PoseFrame> RunEngineDirect(const std::string& model_path, const std::vector<float>& audio,
                                                  int sample_rate, uint64_t seed, float temperature) {
  std::vector<dance::v1::PoseFrame> out;
  auto model = engine::LoadModel(model_path);
  EXPECT_TRUE(model.ok()) << model.status();
  if (!model.ok()) return out;
  engine::SessionOptions o;
  o.input_sample_rate = sample_rate;
  o.input_channels = 1;
  o.seed = seed;
  o.sampling.temperature = temperature;
  auto s = engine::Session::Create(*model, o);
  EXPECT_TRUE(s.ok()) << s.status();
  if (!s.ok()) return out;
  EXPECT_TRUE((*s)->PushAudio(audio).ok());
  (*s)->EndOfAudio();
  while ((*s)->StepsReady() > 0) EXPECT_TRUE((*s)->Step().ok());
  std::vector<engine::PoseFrame> frames;
  (*s)->PopFrames(&frames);
  for (const auto& f : frames) {
    dance::v1::PoseFrame p;
    p.set_index(f.index);
    p.set_time_ms(f.time_s * 1000.0);
    for (int j = 0; j < 24; ++j) {
      for (int k = 0; k < 3; ++k) p.add_positions(f.positions[j][k]);
    }
    p.set_upper_code(f.upper_code);
    p.set_lower_code(f.lower_code);
    out.push_back(p);
  }
  return out;
}

std::vector<float> TestSignal(double seconds, int sample_rate) {
  return engine::testing::TestAudio(seconds, sample_rate);
}

}  // namespace dance::server::testing
