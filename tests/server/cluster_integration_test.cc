// Two real servers in one cluster (a real redis-server, started by the test on a free loopback port): a
// session performed on server A is listed by B, watched through B (relayed: the same frames the performer
// gets), watched by a browser through B's /ws/watch; unknown sessions are NOT_FOUND; a store that goes down
// leaves live sessions dancing and makes cross-server Watch UNAVAILABLE.
#include <arpa/inet.h>
#include <netinet/in.h>
#include <signal.h>
#include <spawn.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <cstring>
#include <map>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/time/clock.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "server/cluster/redis_client.h"
#include "tests/server/testing/server_harness.h"

extern char** environ;

namespace dance::server::testing {
namespace {

using dance::v1::DanceUpdate;

int FreePort() {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  ::inet_pton(AF_INET, "127.0.0.1", &addr.sin_addr);
  ::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof(addr));
  socklen_t len = sizeof(addr);
  ::getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &len);
  ::close(fd);
  return ntohs(addr.sin_port);
}

// redis-server on a free loopback port, no persistence; stopped (by its pid) in the destructor.
class RedisProcess {
 public:
  RedisProcess() {
    port_ = FreePort();
    const std::string port = absl::StrCat(port_);
    std::vector<std::string> args = {"redis-server", "--bind", "127.0.0.1", "--port", port, "--save", "",
                                     "--appendonly", "no", "--loglevel", "warning", "--logfile", "/dev/null"};
    std::vector<char*> argv;
    for (std::string& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    if (posix_spawnp(&pid_, "redis-server", nullptr, nullptr, argv.data(), environ) != 0) pid_ = -1;
    if (pid_ <= 0) return;
    RedisClient c(address(), absl::Milliseconds(200));
    for (int i = 0; i < 100; ++i) {
      if (c.Command({"PING"}).ok()) {
        up_ = true;
        return;
      }
      absl::SleepFor(absl::Milliseconds(50));
    }
  }
  ~RedisProcess() { Stop(); }
  void Stop() {
    if (pid_ <= 0) return;
    ::kill(pid_, SIGTERM);
    ::waitpid(pid_, nullptr, 0);
    pid_ = -1;
  }
  bool up() const { return up_; }
  std::string address() const { return absl::StrCat("127.0.0.1:", port_); }

 private:
  int port_ = 0;
  pid_t pid_ = -1;
  bool up_ = false;
};

std::function<void(DanceServerOptions&)> InCluster(const RedisProcess& redis, const std::string& id) {
  return [&redis, id](DanceServerOptions& o) {
    o.cluster.store_address = redis.address();
    o.cluster.server_id = id;
    o.cluster.heartbeat = absl::Milliseconds(100);
    o.cluster.ttl = absl::Seconds(2);
    o.cluster.lookup_wait = absl::Milliseconds(500);
  };
}

// A performer on a server: streams `seconds` of audio at ~2x real time from its own thread and keeps every
// frame it gets, by index.
class Performer {
 public:
  Performer(const ServerHarness& h, double seconds) : stub_(h.NewStub()), stream_(stub_->Perform(&ctx_)) {
    dance::v1::PerformRequest header;
    header.mutable_header()->set_sample_rate_hz(24000);
    header.mutable_header()->set_channels(1);
    header.mutable_header()->set_sample_format(dance::v1::SAMPLE_FORMAT_F32LE);
    stream_->Write(header);
    DanceUpdate u;
    if (stream_->Read(&u) && u.has_info()) session_id_ = u.info().session_id();
    audio_ = TestSignal(seconds, 24000);
    writer_ = std::thread([this] {
      const size_t chunk = 2400;  // 100 ms
      for (size_t i = 0; i < audio_.size() && !stop_; i += chunk) {
        const size_t n = std::min(chunk, audio_.size() - i);
        dance::v1::PerformRequest r;
        r.mutable_audio()->set_sample_offset(static_cast<int64_t>(i));
        r.mutable_audio()->set_pcm(std::string(reinterpret_cast<const char*>(&audio_[i]), n * sizeof(float)));
        if (!stream_->Write(r)) break;
        absl::SleepFor(absl::Milliseconds(50));
      }
      stream_->WritesDone();
    });
    reader_ = std::thread([this] {
      DanceUpdate update;
      while (stream_->Read(&update)) {
        if (!update.has_frame()) continue;
        std::lock_guard<std::mutex> lock(mu_);
        frames_[update.frame().index()] = update.frame();
      }
    });
  }
  ~Performer() {
    stop_ = true;
    writer_.join();
    reader_.join();
    status_ = stream_->Finish();
  }
  const std::string& session_id() const { return session_id_; }
  // The performer's frame of this index (waits for it a little: the performer's copy may lag the viewer's).
  bool FrameAt(int64_t index, dance::v1::PoseFrame* out) {
    for (int i = 0; i < 200; ++i) {
      {
        std::lock_guard<std::mutex> lock(mu_);
        auto it = frames_.find(index);
        if (it != frames_.end()) {
          *out = it->second;
          return true;
        }
      }
      absl::SleepFor(absl::Milliseconds(10));
    }
    return false;
  }

 private:
  std::unique_ptr<dance::v1::DanceService::Stub> stub_;
  grpc::ClientContext ctx_;
  std::unique_ptr<grpc::ClientReaderWriter<dance::v1::PerformRequest, DanceUpdate>> stream_;
  std::string session_id_;
  std::vector<float> audio_;
  std::atomic<bool> stop_{false};
  std::thread writer_, reader_;
  std::mutex mu_;
  std::map<int64_t, dance::v1::PoseFrame> frames_;
  grpc::Status status_;
};

// The first n frames of Watch(session) on `h`, and the call's status if it ended before.
grpc::Status WatchFrames(const ServerHarness& h, const std::string& session, int n,
                         std::vector<dance::v1::PoseFrame>* frames) {
  auto stub = h.NewStub();
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(30));
  dance::v1::WatchRequest req;
  req.set_session_id(session);
  auto reader = stub->Watch(&ctx, req);
  DanceUpdate u;
  while (static_cast<int>(frames->size()) < n && reader->Read(&u)) {
    if (u.has_frame()) frames->push_back(u.frame());
  }
  if (static_cast<int>(frames->size()) >= n) {
    ctx.TryCancel();
    while (reader->Read(&u)) {
    }
    reader->Finish();
    return grpc::Status::OK;
  }
  return reader->Finish();
}

std::vector<std::string> ListIds(const ServerHarness& h, bool peer_only) {
  auto stub = h.NewStub();
  grpc::ClientContext ctx;
  if (peer_only) ctx.AddMetadata("x-dance-peer", "1");
  dance::v1::ListSessionsResponse resp;
  EXPECT_TRUE(stub->ListSessions(&ctx, {}, &resp).ok());
  std::vector<std::string> ids;
  for (const auto& s : resp.sessions()) ids.push_back(s.session_id());
  return ids;
}

bool Contains(const std::vector<std::string>& v, const std::string& x) {
  return std::find(v.begin(), v.end(), x) != v.end();
}

class Cluster : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!redis_.up()) GTEST_SKIP() << "redis-server not installed or did not start (scripts/install-deps.sh)";
    a_ = std::make_unique<ServerHarness>(InCluster(redis_, "a"));
    b_ = std::make_unique<ServerHarness>(InCluster(redis_, "b"));
    // Both servers have heartbeated and see each other.
    const absl::Time deadline = absl::Now() + absl::Seconds(20);
    while (absl::Now() < deadline && (a_->server().registry() == nullptr ||
                                      a_->server().registry()->Peers().empty() ||
                                      b_->server().registry()->Peers().empty())) {
      absl::SleepFor(absl::Milliseconds(20));
    }
  }
  RedisProcess redis_;
  std::unique_ptr<ServerHarness> a_, b_;
};

TEST_F(Cluster, WatchOnAnotherServerIsRelayedWithThePerformersFrames) {
  ASSERT_EQ(b_->server().registry()->Peers().size(), 1u);
  Performer p(*a_, 8.0);
  ASSERT_FALSE(p.session_id().empty());
  std::vector<dance::v1::PoseFrame> frames;
  // Watched at once: the lookup waits for A's registration if it is not in the store yet.
  grpc::Status st = WatchFrames(*b_, p.session_id(), 20, &frames);
  ASSERT_TRUE(st.ok()) << st.error_message();
  ASSERT_EQ(frames.size(), 20u);
  for (size_t i = 1; i < frames.size(); ++i) {
    EXPECT_GT(frames[i].index(), frames[i - 1].index());
  }
  for (const auto& f : frames) {
    dance::v1::PoseFrame mine;
    ASSERT_TRUE(p.FrameAt(f.index(), &mine)) << "performer never got frame " << f.index();
    ASSERT_EQ(f.positions_size(), mine.positions_size());
    for (int k = 0; k < f.positions_size(); ++k) ASSERT_EQ(f.positions(k), mine.positions(k)) << f.index();
  }
  // The relay was a viewer of A's session and leaves it when the watcher goes.
  const absl::Time deadline = absl::Now() + absl::Seconds(20);
  int viewers = -1;
  while (absl::Now() < deadline) {
    viewers = a_->server().hub().Find(p.session_id())->Summary().viewers;
    if (viewers == 0) break;
    absl::SleepFor(absl::Milliseconds(20));
  }
  EXPECT_EQ(viewers, 0);
}

TEST_F(Cluster, ListSessionsGathersEveryServersSessions) {
  Performer pa(*a_, 6.0);
  Performer pb(*b_, 6.0);
  ASSERT_FALSE(pa.session_id().empty());
  ASSERT_FALSE(pb.session_id().empty());
  for (const ServerHarness* h : {a_.get(), b_.get()}) {
    const std::vector<std::string> all = ListIds(*h, false);
    EXPECT_TRUE(Contains(all, pa.session_id()));
    EXPECT_TRUE(Contains(all, pb.session_id()));
    EXPECT_EQ(all.size(), 2u);
  }
  // A peer call is answered from the server's own sessions only (that is what keeps relays loop-free).
  EXPECT_EQ(ListIds(*b_, true), std::vector<std::string>{pb.session_id()});
}

TEST_F(Cluster, UnknownSessionIsNotFoundEverywhere) {
  std::vector<dance::v1::PoseFrame> frames;
  EXPECT_EQ(WatchFrames(*b_, "s-00000000deadbeef", 1, &frames).error_code(), grpc::StatusCode::NOT_FOUND);
  // A peer call for a session the server does not hold is not relayed again.
  auto stub = b_->NewStub();
  Performer p(*a_, 4.0);
  ASSERT_FALSE(p.session_id().empty());
  grpc::ClientContext ctx;
  ctx.AddMetadata("x-dance-peer", "1");
  dance::v1::WatchRequest req;
  req.set_session_id(p.session_id());
  auto reader = stub->Watch(&ctx, req);
  DanceUpdate u;
  EXPECT_FALSE(reader->Read(&u));
  EXPECT_EQ(reader->Finish().error_code(), grpc::StatusCode::NOT_FOUND);
}

// The browser's /ws/watch on B of a session on A: B hands the socket to A; frames arrive as JSON.
TEST_F(Cluster, BrowserWatchOnAnotherServerIsRelayed) {
  Performer p(*a_, 6.0);
  ASSERT_FALSE(p.session_id().empty());
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<uint16_t>(b_->server().http_port()));
  ::inet_pton(AF_INET, "127.0.0.1", &addr.sin_addr);
  ASSERT_EQ(::connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof(addr)), 0);
  const std::string req = absl::StrCat("GET /ws/watch?session=", p.session_id(),
                                       " HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                                       "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n");
  ASSERT_EQ(::send(fd, req.data(), req.size(), MSG_NOSIGNAL), static_cast<ssize_t>(req.size()));
  std::string in;
  char buf[65536];
  int frames = 0;
  int64_t last_index = -1;
  bool upgraded = false;
  const absl::Time deadline = absl::Now() + absl::Seconds(30);
  while (frames < 5 && absl::Now() < deadline) {
    const ssize_t n = ::recv(fd, buf, sizeof(buf), 0);
    if (n <= 0) break;
    in.append(buf, static_cast<size_t>(n));
    if (!upgraded) {
      const size_t end = in.find("\r\n\r\n");
      if (end == std::string::npos) continue;
      ASSERT_TRUE(absl::StartsWith(in, "HTTP/1.1 101")) << in.substr(0, 200);
      ASSERT_TRUE(absl::StrContains(in.substr(0, end), "s3pPLMBiTxaQ9kYGzzhZRbK+xOo="));
      in.erase(0, end + 4);
      upgraded = true;
    }
    while (frames < 5) {  // whole server frames (unmasked); one recv may hold several
      if (in.size() < 2) break;
      uint64_t len = static_cast<unsigned char>(in[1]) & 0x7F;
      size_t off = 2;
      if (len == 126) {
        if (in.size() < 4) break;
        len = (uint64_t{static_cast<unsigned char>(in[2])} << 8) | static_cast<unsigned char>(in[3]);
        off = 4;
      } else if (len == 127) {
        if (in.size() < 10) break;
        len = 0;
        for (int i = 2; i < 10; ++i) len = (len << 8) | static_cast<unsigned char>(in[i]);
        off = 10;
      }
      if (in.size() < off + len) break;
      const int opcode = in[0] & 0x0F;
      const std::string payload = in.substr(off, len);
      in.erase(0, off + len);
      if (opcode != 1) continue;
      const nlohmann::json j = nlohmann::json::parse(payload);
      if (j.value("type", "") != "frame") continue;
      const int64_t index = j.at("index").get<int64_t>();
      EXPECT_GT(index, last_index);
      last_index = index;
      ++frames;
    }
  }
  ::close(fd);
  EXPECT_TRUE(upgraded);
  EXPECT_EQ(frames, 5);
}

TEST_F(Cluster, StoreDownSessionsDanceOnAndRemoteWatchIsUnavailable) {
  Performer p(*a_, 6.0);
  ASSERT_FALSE(p.session_id().empty());
  redis_.Stop();
  // A's session and a new one keep dancing.
  PerformResult r = RunPerform(a_->NewStub().get(), TestSignal(1.0, 24000), 24000, 5);
  EXPECT_TRUE(r.status.ok()) << r.status.error_message();
  EXPECT_GE(r.frames.size(), 20u);
  std::vector<dance::v1::PoseFrame> frames;
  EXPECT_EQ(WatchFrames(*b_, p.session_id(), 1, &frames).error_code(), grpc::StatusCode::UNAVAILABLE);
  // On its own server the session is still watchable.
  frames.clear();
  EXPECT_TRUE(WatchFrames(*a_, p.session_id(), 3, &frames).ok());
  EXPECT_EQ(frames.size(), 3u);
}

}  // namespace
}  // namespace dance::server::testing
