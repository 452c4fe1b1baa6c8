// Fan-out: what one engine step's 4 frames cost once the engine has made them, published by a live
// session to its performer and V viewers through the real sinks (no network, no engine).
//   BM_FanOutGrpc/V       performer without rotations (as dance-client load) + V gRPC viewers with rotations;
//                         the scheduler thread publishes (and builds each message form once), then every
//                         call's write is serialised as gRPC's StartWrite would.
//   BM_FanOutWebSocket/V  performer + V WebSocket viewers; then every socket's writer takes its JSON text
//                         (built once per form for all sockets).
// Time is per step (4 frames). The engine is a test double that emits frames with varied coordinates.
#include <cmath>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "absl/time/clock.h"
#include "benchmark/benchmark.h"
#include "dance/v1/dance.pb.h"
#include "server/core/live_session.h"
#include "server/core/metrics.h"
#include "server/grpc/stream_writer.h"
#include "server/web/json_codec.h"
#include "server/web/ws_sink.h"

namespace dance::server {
namespace {

// TEST DOUBLE: always one step ready; each step emits 4 frames with non-round coordinates (the JSON
// cost depends on the digits).
class StepStream : public EngineStream {
 public:
  absl::Status PushAudio(absl::Span<const float>) override { return absl::OkStatus(); }
  absl::Status PushAudioInt16(absl::Span<const int16_t>) override { return absl::OkStatus(); }
  void EndOfAudio() override {}
  int StepsReady() const override { return 1; }
  void PopFrames(std::vector<FrameData>* out) override {
    for (; pending_ > 0; --pending_) {
      FrameData f{};
      f.index = next_++;
      f.time_s = static_cast<double>(f.index) / 30.0;
      for (size_t i = 0; i < f.positions.size(); ++i) f.positions[i] = std::sin(0.1f * (f.index + i));
      for (size_t i = 0; i < f.rotations.size(); ++i) f.rotations[i] = std::cos(0.1f * (f.index + i));
      f.upper_code = static_cast<int>(f.index % 512);
      f.lower_code = static_cast<int>((f.index * 7) % 512);
      out->push_back(f);
    }
  }
  absl::Status SetStyle(const StyleMix&) override { return absl::OkStatus(); }
  absl::Status SetSampling(const SamplingConfig&) override { return absl::OkStatus(); }
  void Step() { pending_ += 4; }

 private:
  int64_t next_ = 0;
  int pending_ = 0;
};

// Stands in for a gRPC reactor: a write is serialised (as StartWrite does) and completes when the
// benchmark says so.
class FakeReactor {
 public:
  void IssueWrite(const dance::v1::DanceUpdate* update) {
    update->SerializeToString(&wire_);
    pending_ = true;
  }
  void IssueRead() {}
  void IssueFinish(grpc::Status) {}
  // Completes writes until the writer has nothing queued.
  void Flush(StreamWriter<FakeReactor>* writer) {
    while (pending_) {
      pending_ = false;
      writer->OnWriteDone(true);
    }
  }

 private:
  std::string wire_;
  bool pending_ = false;
};

std::unique_ptr<LiveSession> NewSession(StepStream** stream, ServerMetrics* metrics) {
  auto s = std::make_unique<StepStream>();
  *stream = s.get();
  SessionSettings st;
  st.id = "s-bench";
  return std::make_unique<LiveSession>(st, std::move(s), ModelDescription{}, metrics, absl::Now());
}

void BM_FanOutGrpc(benchmark::State& state) {
  ServerMetrics metrics;
  StepStream* stream = nullptr;
  auto session = NewSession(&stream, &metrics);
  using Writer = StreamWriter<FakeReactor>;
  const int viewers = static_cast<int>(state.range(0));
  std::vector<std::unique_ptr<FakeReactor>> reactors;
  std::vector<std::shared_ptr<Writer>> writers;
  for (int v = 0; v <= viewers; ++v) {
    reactors.push_back(std::make_unique<FakeReactor>());
    const bool performer = v == 0;
    writers.push_back(std::make_shared<Writer>(reactors.back().get(),
                                               performer ? Writer::Mode::kLossless : Writer::Mode::kLossy,
                                               1024, /*wants_rotations=*/!performer, &metrics));
    if (performer) {
      session->AttachPerformer(writers.back());
    } else {
      (void)session->AddViewer(writers.back());
    }
  }
  for (size_t i = 0; i < writers.size(); ++i) reactors[i]->Flush(writers[i].get());
  for (auto _ : state) {
    stream->Step();
    session->AfterStep(absl::Now());
    for (size_t i = 0; i < writers.size(); ++i) reactors[i]->Flush(writers[i].get());
  }
  state.SetItemsProcessed(state.iterations() * 4);
  state.counters["frames_per_step"] = 4;
}
BENCHMARK(BM_FanOutGrpc)->Arg(0)->Arg(1)->Arg(8)->Arg(64);

void BM_FanOutWebSocket(benchmark::State& state) {
  ServerMetrics metrics;
  StepStream* stream = nullptr;
  auto session = NewSession(&stream, &metrics);
  const int viewers = static_cast<int>(state.range(0));
  std::vector<std::shared_ptr<WsSink>> sinks;
  for (int v = 0; v <= viewers; ++v) {
    const bool performer = v == 0;
    sinks.push_back(std::make_shared<WsSink>(/*lossy=*/!performer, performer ? 1024 : 8, true, &metrics));
    if (performer) {
      session->AttachPerformer(sinks.back());
    } else {
      (void)session->AddViewer(sinks.back());
    }
  }
  std::string scratch;
  size_t bytes = 0;
  auto drain = [&] {
    for (const auto& sink : sinks) {
      UpdatePtr u;
      int64_t dropped = 0;
      absl::Status final;
      while (sink->Backlog() > 0 && sink->Next(&u, &dropped, &final)) {
        bytes += UpdateToJson(*u, sink->wants_rotations(), dropped, &scratch).size();
      }
    }
  };
  drain();
  for (auto _ : state) {
    stream->Step();
    session->AfterStep(absl::Now());
    drain();
  }
  benchmark::DoNotOptimize(bytes);
  state.SetItemsProcessed(state.iterations() * 4);
}
BENCHMARK(BM_FanOutWebSocket)->Arg(0)->Arg(1)->Arg(8)->Arg(64);

}  // namespace
}  // namespace dance::server

BENCHMARK_MAIN();
