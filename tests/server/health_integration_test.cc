// The standard gRPC health service (grpc.health.v1.Health/Check) of a real server on a loopback port: it
// answers for "" and for dance.v1.DanceService, NOT_SERVING while the server is full or draining.
//
// Debian ships no health.proto or generated health stubs, so the test speaks the protocol with grpc's
// GenericStub: the request is HealthCheckRequest{string service = 1}, the reply HealthCheckResponse{
// ServingStatus status = 1} with UNKNOWN = 0, SERVING = 1, NOT_SERVING = 2.
#include <future>
#include <string>
#include <thread>

#include <grpcpp/generic/generic_stub.h>

#include "absl/time/clock.h"
#include "gtest/gtest.h"
#include "tests/server/testing/server_harness.h"

namespace dance::server::testing {
namespace {

enum class Health { kUnknown = 0, kServing = 1, kNotServing = 2, kNotFound = 100, kRpcError = 101 };

std::ostream& operator<<(std::ostream& os, Health h) { return os << "Health(" << static_cast<int>(h) << ")"; }

Health Check(const std::shared_ptr<grpc::Channel>& channel, const std::string& service) {
  grpc::GenericStub stub(channel);
  std::string request;
  if (!service.empty()) {
    request.push_back('\x0a');  // field 1, length-delimited
    request.push_back(static_cast<char>(service.size()));
    request += service;
  }
  grpc::Slice slice(request);
  grpc::ByteBuffer in(&slice, 1);
  grpc::ByteBuffer out;
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(20));
  std::promise<grpc::Status> done;
  stub.UnaryCall(&ctx, "/grpc.health.v1.Health/Check", grpc::StubOptions(), &in, &out,
                 [&done](grpc::Status s) { done.set_value(std::move(s)); });
  const grpc::Status status = done.get_future().get();
  if (status.error_code() == grpc::StatusCode::NOT_FOUND) return Health::kNotFound;
  if (!status.ok()) return Health::kRpcError;
  std::vector<grpc::Slice> slices;
  if (!out.Dump(&slices).ok()) return Health::kRpcError;
  std::string reply;
  for (const grpc::Slice& s : slices) reply.append(reinterpret_cast<const char*>(s.begin()), s.size());
  if (reply.empty()) return Health::kUnknown;                             // status = 0 is not encoded
  if (reply.size() != 2 || reply[0] != '\x08') return Health::kRpcError;  // field 1, varint
  return static_cast<Health>(reply[1]);
}

// Waits (generously: CI's two cores are busy) for the health of `service` to become `want`.
Health WaitForHealth(const std::shared_ptr<grpc::Channel>& channel, const std::string& service, Health want) {
  const absl::Time deadline = absl::Now() + absl::Seconds(30);
  Health h = Check(channel, service);
  while (h != want && absl::Now() < deadline) {
    absl::SleepFor(absl::Milliseconds(10));
    h = Check(channel, service);
  }
  return h;
}

constexpr const char* kService = "dance.v1.DanceService";

TEST(Health, AnswersForTheEmptyNameAndTheDanceService) {
  ServerHarness h;
  auto channel = h.NewChannel();
  EXPECT_EQ(Check(channel, ""), Health::kServing);
  EXPECT_EQ(Check(channel, kService), Health::kServing);
  EXPECT_EQ(Check(channel, "dance.v1.NoSuchService"), Health::kNotFound);
}

TEST(Health, NotServingWhileFullServingAgainWhenASessionEnds) {
  ServerHarness h([](DanceServerOptions& o) { o.hub.max_sessions = 1; });
  auto channel = h.NewChannel();
  ASSERT_EQ(Check(channel, kService), Health::kServing);

  // One session fills the server; it stays open until we half-close.
  auto stub = h.NewStub();
  grpc::ClientContext ctx;
  auto stream = stub->Perform(&ctx);
  dance::v1::PerformRequest header;
  header.mutable_header()->set_sample_rate_hz(24000);
  header.mutable_header()->set_channels(1);
  header.mutable_header()->set_sample_format(dance::v1::SAMPLE_FORMAT_F32LE);
  ASSERT_TRUE(stream->Write(header));
  dance::v1::DanceUpdate first;
  ASSERT_TRUE(stream->Read(&first));
  ASSERT_TRUE(first.has_info()) << first.DebugString();

  EXPECT_EQ(WaitForHealth(channel, kService, Health::kNotServing), Health::kNotServing);
  EXPECT_EQ(Check(channel, ""), Health::kNotServing);
  // What NOT_SERVING promises: admission refuses.
  PerformResult refused = RunPerform(h.NewStub().get(), TestSignal(0.2, 24000), 24000, 1);
  EXPECT_EQ(refused.status.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);

  stream->WritesDone();
  dance::v1::DanceUpdate u;
  while (stream->Read(&u)) {
  }
  EXPECT_TRUE(stream->Finish().ok());
  EXPECT_EQ(WaitForHealth(channel, kService, Health::kServing), Health::kServing);
  EXPECT_EQ(Check(channel, ""), Health::kServing);
}

TEST(Health, NotServingWhileDraining) {
  ServerHarness h;
  auto channel = h.NewChannel();
  ASSERT_EQ(Check(channel, kService), Health::kServing);
  EXPECT_TRUE(h.server().Drain(absl::Seconds(1)));  // no sessions: returns at once, the server stays up
  EXPECT_EQ(Check(channel, kService), Health::kNotServing);
  EXPECT_EQ(Check(channel, ""), Health::kNotServing);
  PerformResult refused = RunPerform(h.NewStub().get(), TestSignal(0.2, 24000), 24000, 1);
  EXPECT_EQ(refused.status.error_code(), grpc::StatusCode::UNAVAILABLE);
}

}  // namespace
}  // namespace dance::server::testing
