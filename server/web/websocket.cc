#include "server/web/websocket.h"

#include <openssl/evp.h>
#include <openssl/sha.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include "absl/strings/str_cat.h"

namespace dance::server {

std::string WebSocketAcceptKey(absl::string_view client_key) {
  const std::string joined = absl::StrCat(client_key, "258EAFA5-E914-47DA-95CA-C5AB0DC85B11");
  unsigned char digest[SHA_DIGEST_LENGTH];
  SHA1(reinterpret_cast<const unsigned char*>(joined.data()), joined.size(), digest);
  unsigned char out[4 * ((SHA_DIGEST_LENGTH + 2) / 3) + 1];
  const int n = EVP_EncodeBlock(out, digest, SHA_DIGEST_LENGTH);
  return std::string(reinterpret_cast<char*>(out), n);
}

absl::Status WriteAll(int fd, absl::string_view data) {
  while (!data.empty()) {
    const ssize_t n = ::send(fd, data.data(), data.size(), MSG_NOSIGNAL);
    if (n < 0) {
      if (errno == EINTR) continue;
      return absl::UnavailableError(absl::StrCat("send: ", std::strerror(errno)));
    }
    data.remove_prefix(static_cast<size_t>(n));
  }
  return absl::OkStatus();
}

absl::Status WebSocket::SendFrame(uint8_t opcode, absl::string_view payload) {
  std::string frame;
  frame.reserve(payload.size() + 10);
  frame.push_back(static_cast<char>(0x80 | opcode));  // FIN + opcode; server frames are not masked
  if (payload.size() < 126) {
    frame.push_back(static_cast<char>(payload.size()));
  } else if (payload.size() <= 0xFFFF) {
    frame.push_back(126);
    frame.push_back(static_cast<char>(payload.size() >> 8));
    frame.push_back(static_cast<char>(payload.size() & 0xFF));
  } else {
    frame.push_back(127);
    for (int i = 7; i >= 0; --i) frame.push_back(static_cast<char>((uint64_t{payload.size()} >> (8 * i)) & 0xFF));
  }
  frame.append(payload.data(), payload.size());
  absl::MutexLock lock(&send_mu_);
  if (close_sent_) return absl::FailedPreconditionError("websocket already closed");
  if (opcode == 0x8) close_sent_ = true;
  return WriteAll(fd_, frame);
}

absl::Status WebSocket::SendClose(uint16_t code, absl::string_view reason) {
  std::string payload;
  payload.push_back(static_cast<char>(code >> 8));
  payload.push_back(static_cast<char>(code & 0xFF));
  const absl::string_view r = reason.substr(0, 120);
  payload.append(r.data(), r.size());
  {
    absl::MutexLock lock(&send_mu_);
    if (close_sent_) return absl::OkStatus();
  }
  return SendFrame(0x8, payload);
}

absl::Status WebSocket::ReadExact(char* out, size_t n) {
  while (n > 0) {
    const ssize_t r = ::recv(fd_, out, n, 0);
    if (r == 0) return absl::CancelledError("peer closed the connection");
    if (r < 0) {
      if (errno == EINTR) continue;
      return absl::CancelledError(absl::StrCat("recv: ", std::strerror(errno)));
    }
    out += r;
    n -= static_cast<size_t>(r);
  }
  return absl::OkStatus();
}

absl::StatusOr<WebSocket::Message> WebSocket::Receive() {
  Message msg;
  bool in_fragmented = false;
  while (true) {
    unsigned char head[2];
    absl::Status s = ReadExact(reinterpret_cast<char*>(head), 2);
    if (!s.ok()) return s;
    const bool fin = head[0] & 0x80;
    const uint8_t opcode = head[0] & 0x0F;
    const bool masked = head[1] & 0x80;
    uint64_t len = head[1] & 0x7F;
    if ((head[0] & 0x70) != 0) {
      SendClose(1002, "reserved bits set").IgnoreError();
      return absl::InvalidArgumentError("websocket frame with reserved bits (no extensions negotiated)");
    }
    if (!masked) {
      SendClose(1002, "client frames must be masked").IgnoreError();
      return absl::InvalidArgumentError("unmasked client frame");
    }
    if (len == 126 || len == 127) {
      unsigned char ext[8];
      const int n = len == 126 ? 2 : 8;
      s = ReadExact(reinterpret_cast<char*>(ext), n);
      if (!s.ok()) return s;
      len = 0;
      for (int i = 0; i < n; ++i) len = (len << 8) | ext[i];
    }
    const bool control = opcode & 0x8;
    if (control && (len > 125 || !fin)) {
      SendClose(1002, "bad control frame").IgnoreError();
      return absl::InvalidArgumentError("control frame too long or fragmented");
    }
    if (!control && msg.data.size() + len > max_message_bytes_) {
      SendClose(1009, "message too big").IgnoreError();
      return absl::ResourceExhaustedError(
          absl::StrCat("websocket message larger than ", max_message_bytes_, " bytes"));
    }
    unsigned char mask[4];
    s = ReadExact(reinterpret_cast<char*>(mask), 4);
    if (!s.ok()) return s;
    std::string payload(len, '\0');
    if (len > 0) {
      s = ReadExact(payload.data(), len);
      if (!s.ok()) return s;
      for (uint64_t i = 0; i < len; ++i) payload[i] = static_cast<char>(payload[i] ^ mask[i % 4]);
    }
    switch (opcode) {
      case 0x8:  // close: answer and stop
        SendClose(1000, "").IgnoreError();
        return absl::CancelledError("peer sent close");
      case 0x9:  // ping
        s = SendFrame(0xA, payload);
        if (!s.ok()) return s;
        continue;
      case 0xA:  // pong
        continue;
      case 0x0:  // continuation
        if (!in_fragmented) return absl::InvalidArgumentError("continuation frame without a start");
        msg.data.append(payload);
        break;
      case 0x1:
      case 0x2:
        if (in_fragmented) return absl::InvalidArgumentError("new data frame inside a fragmented message");
        msg.binary = opcode == 0x2;
        msg.data = std::move(payload);
        in_fragmented = true;
        break;
      default:
        SendClose(1002, "unknown opcode").IgnoreError();
        return absl::InvalidArgumentError(absl::StrCat("unknown websocket opcode ", opcode));
    }
    if (fin) return msg;
  }
}

}  // namespace dance::server
