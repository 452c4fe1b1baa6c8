// Integration: misbehaving clients get the right status and everybody else keeps being served.
#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <thread>
#include <vector>

#include <grpcpp/generic/generic_stub.h>
#include <grpcpp/health_check_service_interface.h>

#include "absl/strings/match.h"
#include "absl/time/clock.h"
#include "gtest/gtest.h"
#include "tests/server/testing/server_harness.h"

namespace dance::server::testing {
namespace {

using dance::v1::DanceUpdate;
using dance::v1::PerformRequest;

PerformRequest Header(int rate = 24000, int channels = 1,
                      dance::v1::SampleFormat fmt = dance::v1::SAMPLE_FORMAT_F32LE) {
  PerformRequest r;
  r.mutable_header()->set_sample_rate_hz(rate);
  r.mutable_header()->set_channels(channels);
  r.mutable_header()->set_sample_format(fmt);
  return r;
}

PerformRequest Audio(int64_t offset, size_t bytes) {
  PerformRequest r;
  r.mutable_audio()->set_sample_offset(offset);
  r.mutable_audio()->set_pcm(std::string(bytes, '\0'));
  return r;
}

// Sends `requests`, half-closes, drains the responses and returns the final status.
grpc::Status Exchange(dance::v1::DanceService::Stub* stub, const std::vector<PerformRequest>& requests) {
  grpc::ClientContext ctx;
  auto stream = stub->Perform(&ctx);
  for (const auto& r : requests) {
    if (!stream->Write(r)) break;
  }
  stream->WritesDone();
  DanceUpdate u;
  while (stream->Read(&u)) {
  }
  return stream->Finish();
}

// A healthy session still works and gets its whole dance.
void ExpectServing(const ServerHarness& h) {
  auto stub = h.NewStub();
  PerformResult r = RunPerform(stub.get(), TestSignal(1.0, 24000), 24000, 3);
  ASSERT_TRUE(r.status.ok()) << r.status.error_message();
  EXPECT_TRUE(r.got_end);
  EXPECT_GE(r.frames.size(), 20u);
}

// Polls `done` until it holds or a generous deadline passes (the machine may be loaded: CI runs on two
// busy cores). Returns its last value.
template <typename F>
bool WaitFor(F done, absl::Duration timeout = absl::Seconds(60)) {
  const absl::Time deadline = absl::Now() + timeout;
  while (!done()) {
    if (absl::Now() > deadline) return done();
    absl::SleepFor(absl::Milliseconds(5));
  }
  return true;
}

void WaitForNoSessions(ServerHarness& h) {
  EXPECT_TRUE(WaitFor([&] { return h.server().hub().active_sessions() == 0; }))
      << h.server().hub().active_sessions() << " sessions still live";
}

TEST(BadClients, ProtocolViolationsAreInvalidArgument) {
  ServerHarness h([](DanceServerOptions& o) { o.service.limits.max_chunk_samples = 4800; });
  auto stub = h.NewStub();
  struct Case {
    const char* name;
    std::vector<PerformRequest> requests;
    const char* message_part;
  };
  PerformRequest end;
  end.mutable_end();
  PerformRequest empty;
  const std::vector<Case> cases = {
      {"no header at all", {}, "before a StreamHeader"},
      {"audio before header", {Audio(0, 400)}, "audio before the StreamHeader"},
      {"absurd sample rate", {Header(1)}, "sample_rate_hz"},
      {"huge sample rate", {Header(10'000'000)}, "sample_rate_hz"},
      {"zero channels", {Header(24000, 0)}, "channels"},
      {"no sample format", {Header(24000, 1, dance::v1::SAMPLE_FORMAT_UNSPECIFIED)}, "sample_format"},
      {"oversized chunk", {Header(), Audio(0, 4801 * 4)}, "exceeds the limit"},
      {"partial sample", {Header(), Audio(0, 7)}, "whole number"},
      {"offset gap", {Header(), Audio(0, 400), Audio(500, 400)}, "sample_offset"},
      {"two headers", {Header(), Header()}, "twice"},
      // The server may complete the session before it reads the chunk; its OK finish waits for the
      // half-close, so the violation is always seen.
      {"audio after end", {Header(), end, Audio(0, 400)}, "after EndOfAudio"},
      {"audio after end of real audio", {Header(), Audio(0, 4800 * 4), end, Audio(4800, 400)}, "after EndOfAudio"},
      {"two ends", {Header(), end, end}, "twice"},
      {"empty message", {Header(), empty}, "empty"},
  };
  for (const Case& c : cases) {
    grpc::Status st = Exchange(stub.get(), c.requests);
    EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << c.name << ": " << st.error_message();
    EXPECT_TRUE(absl::StrContains(st.error_message(), c.message_part)) << c.name << ": " << st.error_message();
  }
  WaitForNoSessions(h);
  ExpectServing(h);
  EXPECT_GT(h.server().metrics().errors(absl::StatusCode::kInvalidArgument), 0u);
}

TEST(BadClients, GarbageBytesAreRejectedAndTheServerSurvives) {
  ServerHarness h;
  // Not a protobuf at all, through the generic (byte-level) API.
  grpc::GenericStub generic(h.NewChannel());
  grpc::ClientContext ctx;
  grpc::CompletionQueue cq;
  auto call = generic.PrepareCall(&ctx, "/dance.v1.DanceService/Perform", &cq);
  void* tag;
  bool ok;
  call->StartCall(reinterpret_cast<void*>(1));
  ASSERT_TRUE(cq.Next(&tag, &ok));
  const std::string junk = "\xff\xff\xff\xff\x0f garbage \x80\x80\x80";
  grpc::Slice slice(junk);
  grpc::ByteBuffer buf(&slice, 1);
  call->Write(buf, reinterpret_cast<void*>(2));
  ASSERT_TRUE(cq.Next(&tag, &ok));
  call->WritesDone(reinterpret_cast<void*>(3));
  ASSERT_TRUE(cq.Next(&tag, &ok));
  grpc::Status st;
  call->Finish(&st, reinterpret_cast<void*>(4));
  while (cq.Next(&tag, &ok) && tag != reinterpret_cast<void*>(4)) {
  }
  EXPECT_FALSE(st.ok());
  cq.Shutdown();
  while (cq.Next(&tag, &ok)) {
  }

  // Raw garbage on the TCP port (not even HTTP/2).
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<uint16_t>(h.server().port()));
  ::inet_pton(AF_INET, "127.0.0.1", &addr.sin_addr);
  ASSERT_EQ(::connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof(addr)), 0);
  const std::string noise(4096, '\x5a');
  EXPECT_GT(::send(fd, noise.data(), noise.size(), MSG_NOSIGNAL), 0);
  ::close(fd);
  WaitForNoSessions(h);
  ExpectServing(h);
}

TEST(BadClients, AdmissionControlSaysResourceExhausted) {
  ServerHarness h([](DanceServerOptions& o) { o.hub.max_sessions = 2; });
  auto stub = h.NewStub();
  grpc::ClientContext c1, c2;
  auto s1 = stub->Perform(&c1);
  auto s2 = stub->Perform(&c2);
  DanceUpdate u;
  ASSERT_TRUE(s1->Write(Header()));
  ASSERT_TRUE(s1->Read(&u));
  ASSERT_TRUE(s2->Write(Header()));
  ASSERT_TRUE(s2->Read(&u));
  grpc::Status st = Exchange(stub.get(), {Header()});
  EXPECT_EQ(st.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_TRUE(absl::StrContains(st.error_message(), "capacity")) << st.error_message();
  EXPECT_EQ(h.server().metrics().sessions_rejected_total.load(), 1u);
  c1.TryCancel();
  c2.TryCancel();
  s1->Finish();
  s2->Finish();
  WaitForNoSessions(h);
  ExpectServing(h);
}

TEST(BadClients, VanishingClientIsCleanedUp) {
  ServerHarness h;
  auto stub = h.NewStub();
  {
    grpc::ClientContext ctx;
    auto s = stub->Perform(&ctx);
    ASSERT_TRUE(s->Write(Header()));
    const std::vector<float> audio = TestSignal(1.0, 24000);
    PerformRequest a;
    a.mutable_audio()->set_pcm(reinterpret_cast<const char*>(audio.data()), 12000 * sizeof(float));
    ASSERT_TRUE(s->Write(a));
    DanceUpdate u;
    ASSERT_TRUE(s->Read(&u));
    ctx.TryCancel();  // gone mid-stream, no EndOfAudio
    s->Finish();
  }
  WaitForNoSessions(h);
  EXPECT_TRUE(WaitFor([&] { return h.server().metrics().errors(absl::StatusCode::kCancelled) >= 1; }));
  ExpectServing(h);
}

TEST(BadClients, EndWithoutHalfCloseStillFinishesOkAfterTheGrace) {
  ServerHarness h([](DanceServerOptions& o) { o.service.half_close_grace = absl::Milliseconds(300); });
  auto stub = h.NewStub();
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(60));
  auto s = stub->Perform(&ctx);
  ASSERT_TRUE(s->Write(Header()));
  const std::vector<float> audio = TestSignal(1.0, 24000);
  PerformRequest a;
  a.mutable_audio()->set_pcm(reinterpret_cast<const char*>(audio.data()), audio.size() * sizeof(float));
  ASSERT_TRUE(s->Write(a));
  PerformRequest end;
  end.mutable_end();
  ASSERT_TRUE(s->Write(end));
  // No WritesDone: the server must not wait for a half-close forever.
  int64_t frames = 0;
  bool got_end = false;
  DanceUpdate u;
  while (s->Read(&u)) {
    frames += u.has_frame();
    got_end |= u.has_end();
  }
  const grpc::Status st = s->Finish();
  EXPECT_TRUE(st.ok()) << st.error_code() << ": " << st.error_message();
  EXPECT_TRUE(got_end);
  EXPECT_GE(frames, 20);
}

TEST(BadClients, IdleSessionTimesOut) {
  ServerHarness h([](DanceServerOptions& o) { o.hub.idle_timeout = absl::Milliseconds(300); });
  auto stub = h.NewStub();
  grpc::ClientContext ctx;
  auto s = stub->Perform(&ctx);
  ASSERT_TRUE(s->Write(Header()));
  DanceUpdate u;
  while (s->Read(&u)) {
  }
  grpc::Status st = s->Finish();
  EXPECT_EQ(st.error_code(), grpc::StatusCode::DEADLINE_EXCEEDED) << st.error_message();
  ExpectServing(h);
}

TEST(BadClients, PerformerThatNeverReadsIsCutOffOthersUnaffected) {
  ServerHarness h([](DanceServerOptions& o) { o.hub.stall_timeout = absl::Milliseconds(300); });
  // A small, fixed receive window so unread frames back up into the server quickly.
  grpc::ChannelArguments args;
  args.SetInt(GRPC_ARG_USE_LOCAL_SUBCHANNEL_POOL, 1);
  args.SetInt(GRPC_ARG_HTTP2_BDP_PROBE, 0);
  args.SetInt(GRPC_ARG_HTTP2_STREAM_LOOKAHEAD_BYTES, 16 * 1024);
  auto stub = dance::v1::DanceService::NewStub(
      grpc::CreateCustomChannel(h.target(), grpc::InsecureChannelCredentials(), args));
  grpc::ClientContext ctx;
  auto s = stub->Perform(&ctx);
  ASSERT_TRUE(s->Write(Header()));
  const std::vector<float> audio = TestSignal(60.0, 24000);
  bool write_ok = true;
  for (size_t off = 0; write_ok && off < audio.size(); off += 24000) {
    PerformRequest a;
    a.mutable_audio()->set_sample_offset(static_cast<int64_t>(off));
    a.mutable_audio()->set_pcm(reinterpret_cast<const char*>(audio.data() + off), 24000 * sizeof(float));
    write_ok = s->Write(a);
  }
  s->WritesDone();
  // Do not read until the server has given up on us (or 60 s have passed).
  WaitFor([&] { return h.server().metrics().errors(absl::StatusCode::kResourceExhausted) > 0; });
  // Only now read: the server must have given up on us.
  DanceUpdate u;
  while (s->Read(&u)) {
  }
  grpc::Status st = s->Finish();
  EXPECT_EQ(st.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << st.error_message();
  WaitForNoSessions(h);
  ExpectServing(h);
}

TEST(BadClients, WatcherThatNeverReadsNeverSlowsThePerformer) {
  ServerHarness h([](DanceServerOptions& o) { o.service.viewer_queue_frames = 4; });
  auto stub = h.NewStub();
  grpc::ClientContext ctx;
  auto s = stub->Perform(&ctx);
  ASSERT_TRUE(s->Write(Header()));
  DanceUpdate info;
  ASSERT_TRUE(s->Read(&info));
  // A watcher that subscribes and then never reads a byte (small fixed receive window, so its unread
  // frames back up into the server instead of into transport buffers).
  grpc::ChannelArguments wargs;
  wargs.SetInt(GRPC_ARG_USE_LOCAL_SUBCHANNEL_POOL, 1);
  wargs.SetInt(GRPC_ARG_HTTP2_BDP_PROBE, 0);
  wargs.SetInt(GRPC_ARG_HTTP2_STREAM_LOOKAHEAD_BYTES, 16 * 1024);
  auto wstub = dance::v1::DanceService::NewStub(
      grpc::CreateCustomChannel(h.target(), grpc::InsecureChannelCredentials(), wargs));
  grpc::ClientContext wctx;
  dance::v1::WatchRequest wr;
  wr.set_session_id(info.info().session_id());
  auto lazy = wstub->Watch(&wctx, wr);
  ASSERT_FALSE(info.info().session_id().empty());
  WaitFor([&] { return h.server().metrics().viewers_active.load() > 0; });
  ASSERT_EQ(h.server().metrics().viewers_active.load(), 1);
  const std::vector<float> audio = TestSignal(30.0, 24000);
  std::thread writer([&] {
    for (size_t off = 0; off < audio.size(); off += 4800) {
      PerformRequest a;
      a.mutable_audio()->set_sample_offset(static_cast<int64_t>(off));
      a.mutable_audio()->set_pcm(reinterpret_cast<const char*>(audio.data() + off), 4800 * sizeof(float));
      if (!s->Write(a)) return;
    }
    PerformRequest e;
    e.mutable_end();
    s->Write(e);
    s->WritesDone();
  });
  int64_t frames = 0, last = -1;
  bool contiguous = true;
  DanceUpdate u;
  while (s->Read(&u)) {
    if (u.has_frame()) {
      if (last >= 0 && u.frame().index() != last + 1) contiguous = false;
      last = u.frame().index();
      ++frames;
    }
  }
  writer.join();
  ASSERT_TRUE(s->Finish().ok());
  EXPECT_TRUE(contiguous);
  EXPECT_GE(frames, 890);  // 30 s at 30 fps, minus the first period
  EXPECT_GT(h.server().metrics().viewer_frames_dropped_total.load(), 0u);
  wctx.TryCancel();
  lazy->Finish();
}

TEST(BadClients, ThousandSessionsOpenedAndDropped) {
  ServerHarness h([](DanceServerOptions& o) { o.hub.max_sessions = 64; });
  auto stub = h.NewStub();
  for (int i = 0; i < 1000; ++i) {
    grpc::ClientContext ctx;
    auto s = stub->Perform(&ctx);
    s->Write(Header());
    if (i % 2 == 0) {
      DanceUpdate u;
      s->Read(&u);  // half of them get as far as a session
    }
    ctx.TryCancel();
    s->Finish();
  }
  WaitForNoSessions(h);
  EXPECT_GE(h.server().metrics().sessions_started_total.load(), 500u);
  EXPECT_EQ(h.server().metrics().sessions_started_total.load(), h.server().metrics().sessions_finished_total.load());
  ExpectServing(h);
}

TEST(BadClients, BearerTokenIsRequiredWhenConfigured) {
  ServerHarness h([](DanceServerOptions& o) { o.service.auth_token = "s3cret"; });
  auto stub = h.NewStub();
  EXPECT_EQ(Exchange(stub.get(), {Header()}).error_code(), grpc::StatusCode::UNAUTHENTICATED);
  grpc::ClientContext ctx;
  dance::v1::ModelInfo mi;
  EXPECT_EQ(stub->GetModelInfo(&ctx, {}, &mi).error_code(), grpc::StatusCode::UNAUTHENTICATED);
  grpc::ClientContext ok_ctx;
  ok_ctx.AddMetadata("authorization", "Bearer s3cret");
  EXPECT_TRUE(stub->GetModelInfo(&ok_ctx, {}, &mi).ok());
}

TEST(BadClients, DrainRefusesNewSessionsAndReportsNotServing) {
  ServerHarness h;
  auto stub = h.NewStub();
  EXPECT_TRUE(h.server().Drain(absl::Milliseconds(100)));
  EXPECT_EQ(Exchange(stub.get(), {Header()}).error_code(), grpc::StatusCode::UNAVAILABLE);
  EXPECT_FALSE(h.server().hub().serving());
}

TEST(BadClients, WatchUnknownSessionIsNotFound) {
  ServerHarness h;
  auto stub = h.NewStub();
  grpc::ClientContext ctx;
  dance::v1::WatchRequest wr;
  wr.set_session_id("s-nope");
  auto r = stub->Watch(&ctx, wr);
  DanceUpdate u;
  EXPECT_FALSE(r->Read(&u));
  EXPECT_EQ(r->Finish().error_code(), grpc::StatusCode::NOT_FOUND);
}

}  // namespace
}  // namespace dance::server::testing
