// Test harness: a real DanceServer (real engine, the tiny model) on port 0, plus helpers to talk to it.
//
//   ServerHarness h;                       // starts with default options
//   ServerHarness h([](DanceServerOptions& o) { o.hub.max_sessions = 3; });
//   auto stub = h.NewStub();
//   PerformResult r = RunPerform(stub.get(), audio, 24000, /*seed=*/1);
//
// The model is models/test-tiny.dncw when the repository has it, otherwise the engine tests' C++ tiny
// model written to a temporary file (same format, random weights).
#ifndef DANCE_TESTS_SERVER_TESTING_SERVER_HARNESS_H_
#define DANCE_TESTS_SERVER_TESTING_SERVER_HARNESS_H_

#include <functional>
#include <memory>
#include <string>
#include <vector>

#include <grpcpp/grpcpp.h>

#include "dance/v1/dance.grpc.pb.h"
#include "server/dance_server.h"

namespace dance::server::testing {

std::string TinyModelPath();

class ServerHarness {
 public:
  explicit ServerHarness(std::function<void(DanceServerOptions&)> configure = nullptr,
                         const std::string& model_path = "");  // "" = TinyModelPath()
  ~ServerHarness();
  DanceServer& server() { return *server_; }
  std::string target() const;
  std::unique_ptr<dance::v1::DanceService::Stub> NewStub() const;
  std::shared_ptr<grpc::Channel> NewChannel() const;

 private:
  std::unique_ptr<DanceServer> server_;
};

struct PerformResult {
  grpc::Status status;
  dance::v1::SessionInfo info;
  std::vector<dance::v1::PoseFrame> frames;
  std::vector<dance::v1::Event> events;
  dance::v1::StreamEnd end;
  bool got_end = false;
};

// Streams mono float audio (chunk_frames per message, as fast as possible) with the blocking API.
PerformResult RunPerform(dance::v1::DanceService::Stub* stub, const std::vector<float>& audio, int sample_rate,
                         uint64_t seed, int chunk_frames = 4800, float temperature = 1.0f);

// The same audio through the engine directly (no server): the reference dance.
std::vector<dance::v1::PoseFrame> RunEngineDirect(const std::string& model_path, const std::vector<float>& audio,
                                                  int sample_rate, uint64_t seed, float temperature = 1.0f);

// A deterministic test signal (clicks on a beat grid over a tone), mono.
std::vector<float> TestSignal(double seconds, int sample_rate);

}  // namespace dance::server::testing

#endif  // DANCE_TESTS_SERVER_TESTING_SERVER_HARNESS_H_
