// Minimal RFC 6455 WebSocket server side over a connected, blocking POSIX socket.
//
// Usage:
//   std::string accept = WebSocketAcceptKey(request_key);        // for the 101 response
//   WebSocket ws(fd, /*max_message_bytes=*/1 << 20);
//   ws.SendText("{\"type\":\"info\"}");
//   absl::StatusOr<WebSocket::Message> m = ws.Receive();         // handles ping/pong/close itself
//
// Supports text and binary messages, fragmentation, ping/pong and close; no extensions (no compression).
// Client frames must be masked (RFC 6455 5.1). Oversized messages fail with RESOURCE_EXHAUSTED and a 1009
// close frame.
// Thread safety: one thread may Receive while others Send (sends are serialised by an internal mutex).
// The WebSocket does not own the fd.
#ifndef DANCE_SERVER_WEB_WEBSOCKET_H_
#define DANCE_SERVER_WEB_WEBSOCKET_H_

#include <cstddef>
#include <cstdint>
#include <string>
#include "absl/strings/string_view.h"

#include "absl/base/thread_annotations.h"
#include "absl/status/statusor.h"
#include "absl/synchronization/mutex.h"

namespace dance::server {

// base64(SHA-1(key + "258EAFA5-E914-47DA-95CA-C5AB0DC85B11")).
std::string WebSocketAcceptKey(absl::string_view client_key);

// Writes all bytes (retrying on EINTR / short writes). UNAVAILABLE when the peer is gone.
absl::Status WriteAll(int fd, absl::string_view data);

class WebSocket {
 public:
  struct Message {
    bool binary = false;
    std::string data;
  };

  WebSocket(int fd, size_t max_message_bytes) : fd_(fd), max_message_bytes_(max_message_bytes) {}

  absl::Status SendText(absl::string_view text) { return SendFrame(0x1, text); }
  absl::Status SendBinary(absl::string_view data) { return SendFrame(0x2, data); }
  // Sends a close frame once (code 1000 normal, 1008 policy, 1009 too big, 1011 internal).
  absl::Status SendClose(uint16_t code, absl::string_view reason);
  // Blocks for the next data message. CANCELLED when the peer closed (a close frame or EOF).
  absl::StatusOr<Message> Receive();

 private:
  absl::Status SendFrame(uint8_t opcode, absl::string_view payload);
  absl::Status ReadExact(char* out, size_t n);

  const int fd_;
  const size_t max_message_bytes_;
  absl::Mutex send_mu_;
  bool close_sent_ ABSL_GUARDED_BY(send_mu_) = false;
};

}  // namespace dance::server

#endif  // DANCE_SERVER_WEB_WEBSOCKET_H_
