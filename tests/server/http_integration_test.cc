// Integration: the HTTP side of a real server: /metrics, /api, static fallback, and the WebSocket
// perform/watch protocol of docs/protocol.md, spoken by a minimal blocking client below.
#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cstring>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "tests/server/testing/server_harness.h"

namespace dance::server::testing {
namespace {

using nlohmann::json;

int Connect(int port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<uint16_t>(port));
  ::inet_pton(AF_INET, "127.0.0.1", &addr.sin_addr);
  if (::connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof(addr)) != 0) {
    ::close(fd);
    return -1;
  }
  return fd;
}

std::string ReadAll(int fd) {
  std::string out;
  char buf[4096];
  ssize_t n;
  while ((n = ::recv(fd, buf, sizeof(buf), 0)) > 0) out.append(buf, static_cast<size_t>(n));
  return out;
}

std::string HttpGet(int port, const std::string& path) {
  const int fd = Connect(port);
  const std::string req = absl::StrCat("GET ", path, " HTTP/1.1\r\nHost: x\r\n\r\n");
  ::send(fd, req.data(), req.size(), MSG_NOSIGNAL);
  std::string resp = ReadAll(fd);
  ::close(fd);
  return resp;
}

// Blocking WebSocket client (test helper): masked client frames, unmasked server frames.
class WsClient {
 public:
  bool Open(int port, const std::string& path) {
    fd_ = Connect(port);
    const std::string req = absl::StrCat("GET ", path,
                                         " HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                                         "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
                                         "Sec-WebSocket-Version: 13\r\n\r\n");
    ::send(fd_, req.data(), req.size(), MSG_NOSIGNAL);
    std::string head;
    char c;
    while (head.find("\r\n\r\n") == std::string::npos && ::recv(fd_, &c, 1, 0) == 1) head.push_back(c);
    status_line_ = head.substr(0, head.find("\r\n"));
    return absl::StrContains(head, " 101 ") && absl::StrContains(head, "s3pPLMBiTxaQ9kYGzzhZRbK+xOo=");
  }
  ~WsClient() {
    if (fd_ >= 0) ::close(fd_);
  }
  void Send(uint8_t opcode, const std::string& payload) {
    std::string f;
    f.push_back(static_cast<char>(0x80 | opcode));
    if (payload.size() < 126) {
      f.push_back(static_cast<char>(0x80 | payload.size()));
    } else {
      f.push_back(static_cast<char>(0x80 | 127));
      for (int i = 7; i >= 0; --i) f.push_back(static_cast<char>((uint64_t{payload.size()} >> (8 * i)) & 0xFF));
    }
    const char mask[4] = {0x12, 0x34, 0x56, 0x78};
    f.append(mask, 4);
    for (size_t i = 0; i < payload.size(); ++i) f.push_back(static_cast<char>(payload[i] ^ mask[i % 4]));
    ::send(fd_, f.data(), f.size(), MSG_NOSIGNAL);
  }
  void SendText(const std::string& s) { Send(0x1, s); }
  void SendBinary(const std::string& s) { Send(0x2, s); }
  // Next message; opcode 8 = close, -1 = connection gone.
  int Receive(std::string* payload) {
    unsigned char h[2];
    if (!Exact(reinterpret_cast<char*>(h), 2)) return -1;
    uint64_t len = h[1] & 0x7F;
    if (len >= 126) {
      unsigned char e[8];
      const int n = len == 126 ? 2 : 8;
      if (!Exact(reinterpret_cast<char*>(e), n)) return -1;
      len = 0;
      for (int i = 0; i < n; ++i) len = (len << 8) | e[i];
    }
    payload->assign(len, '\0');
    if (len > 0 && !Exact(payload->data(), len)) return -1;
    return h[0] & 0x0F;
  }
  const std::string& status_line() const { return status_line_; }

 private:
  bool Exact(char* out, size_t n) {
    while (n > 0) {
      const ssize_t r = ::recv(fd_, out, n, 0);
      if (r <= 0) return false;
      out += r;
      n -= static_cast<size_t>(r);
    }
    return true;
  }
  int fd_ = -1;
  std::string status_line_;
};

TEST(HttpIntegration, MetricsApiAndFallbackPage) {
  ServerHarness h;
  auto stub = h.NewStub();
  PerformResult r = RunPerform(stub.get(), TestSignal(1.0, 24000), 24000, 1);
  ASSERT_TRUE(r.status.ok());
  const int port = h.server().http_port();
  const std::string metrics = HttpGet(port, "/metrics");
  EXPECT_TRUE(absl::StartsWith(metrics, "HTTP/1.1 200")) << metrics.substr(0, 80);
  for (const char* name : {"dance_sessions_active 0", "dance_frames_total ", "dance_step_latency_seconds_bucket",
                           "dance_viewer_frames_dropped_total", "dance_sessions_rejected_total",
                           "dance_errors_total{kind=\"invalid_argument\"}"}) {
    EXPECT_TRUE(absl::StrContains(metrics, name)) << name;
  }
  EXPECT_TRUE(absl::StrContains(metrics, absl::StrCat("dance_frames_total ", r.frames.size(), "\n")));
  const std::string sessions = HttpGet(port, "/api/sessions");
  EXPECT_TRUE(absl::StrContains(sessions, "{\"sessions\":[]}")) << sessions;
  const std::string model = HttpGet(port, "/api/model");
  EXPECT_TRUE(absl::StrContains(model, "\"joint_names\""));
  EXPECT_TRUE(absl::StrContains(HttpGet(port, "/"), "dance-server"));
  EXPECT_TRUE(absl::StartsWith(HttpGet(port, "/../etc/passwd"), "HTTP/1.1 400"));
  EXPECT_TRUE(absl::StartsWith(HttpGet(port, "/nope.js"), "HTTP/1.1 404"));
  EXPECT_TRUE(absl::StartsWith(HttpGet(port, "/ws/watch?session=s-none"), "HTTP/1.1 404"));
  EXPECT_TRUE(absl::StartsWith(HttpGet(port, "/healthz"), "HTTP/1.1 200"));
}

TEST(HttpIntegration, WebSocketPerformAndWatchMatchTheGrpcDance) {
  ServerHarness h;
  const int port = h.server().http_port();
  WsClient perf;
  ASSERT_TRUE(perf.Open(port, "/ws/perform")) << perf.status_line();
  perf.SendText(R"({"type": "start", "sample_rate": 24000, "channels": 1, "seed": 5, "client_name": "ws-test"})");
  std::string msg;
  ASSERT_EQ(perf.Receive(&msg), 1);
  json info = json::parse(msg);
  ASSERT_EQ(info["type"], "info");
  ASSERT_EQ(info["joint_names"].size(), 24u);
  const std::string id = info["session_id"];

  WsClient watch;
  ASSERT_TRUE(watch.Open(port, "/ws/watch?session=" + id));
  ASSERT_EQ(watch.Receive(&msg), 1);
  EXPECT_EQ(json::parse(msg)["type"], "info");

  const std::vector<float> audio = TestSignal(2.0, 24000);
  for (size_t off = 0; off < audio.size(); off += 2400) {
    perf.SendBinary(std::string(reinterpret_cast<const char*>(audio.data() + off), 2400 * sizeof(float)));
  }
  perf.SendText(R"({"type": "end"})");
  std::vector<json> frames;
  bool ended = false;
  while (true) {
    const int op = perf.Receive(&msg);
    if (op != 1) break;
    json j = json::parse(msg);
    if (j["type"] == "frame") frames.push_back(j);
    if (j["type"] == "end") ended = true;
  }
  EXPECT_TRUE(ended);
  std::vector<json> watched;
  while (watch.Receive(&msg) == 1) {
    json j = json::parse(msg);
    if (j["type"] == "frame") watched.push_back(j);
  }
  std::vector<dance::v1::PoseFrame> ref = RunEngineDirect(TinyModelPath(), audio, 24000, 5);
  ASSERT_EQ(frames.size(), ref.size());
  for (size_t i = 0; i < ref.size(); ++i) {
    ASSERT_EQ(frames[i]["index"], ref[i].index());
    ASSERT_EQ(frames[i]["upper_code"], ref[i].upper_code());
    ASSERT_EQ(frames[i]["positions"].size(), 72u);
    ASSERT_FLOAT_EQ(frames[i]["positions"][7].get<float>(), ref[i].positions(7));
    ASSERT_EQ(frames[i]["rotations"].size(), 96u);
  }
  // The viewer may drop frames (newest wins) but never invents or reorders them.
  ASSERT_FALSE(watched.empty());
  int64_t prev = -1;
  for (const json& w : watched) {
    const int64_t idx = w["index"];
    EXPECT_GT(idx, prev);
    prev = idx;
  }
}

TEST(HttpIntegration, WebSocketAudioBeforeStartIsAnError) {
  ServerHarness h;
  WsClient ws;
  ASSERT_TRUE(ws.Open(h.server().http_port(), "/ws/perform"));
  ws.SendBinary(std::string(400, '\0'));
  std::string msg;
  ASSERT_EQ(ws.Receive(&msg), 1);
  json j = json::parse(msg);
  EXPECT_EQ(j["type"], "error");
  EXPECT_EQ(j["code"], "INVALID_ARGUMENT");
  EXPECT_EQ(ws.Receive(&msg), 8);  // close frame
}

}  // namespace
}  // namespace dance::server::testing
