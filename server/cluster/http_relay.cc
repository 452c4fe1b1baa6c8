#include "server/cluster/http_relay.h"

#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cctype>
#include <cerrno>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"

namespace dance::server {
namespace {

std::string UrlEncode(const std::string& in) {
  static const char kHex[] = "0123456789ABCDEF";
  std::string out;
  for (unsigned char c : in) {
    if (std::isalnum(c) || c == '-' || c == '_' || c == '.' || c == '~') {
      out.push_back(static_cast<char>(c));
    } else {
      out.push_back('%');
      out.push_back(kHex[c >> 4]);
      out.push_back(kHex[c & 15]);
    }
  }
  return out;
}

bool WriteAll(int fd, const char* data, size_t n) {
  while (n > 0) {
    const ssize_t w = ::send(fd, data, n, MSG_NOSIGNAL);
    if (w < 0 && errno == EINTR) continue;
    if (w <= 0) return false;
    data += w;
    n -= static_cast<size_t>(w);
  }
  return true;
}

int Connect(const std::string& address) {
  const size_t colon = address.rfind(':');
  if (colon == std::string::npos) return -1;
  const std::string host = address.substr(0, colon);
  const std::string port = address.substr(colon + 1);
  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  addrinfo* res = nullptr;
  if (::getaddrinfo(host.c_str(), port.c_str(), &hints, &res) != 0) return -1;
  int fd = -1;
  for (addrinfo* a = res; a != nullptr; a = a->ai_next) {
    fd = ::socket(a->ai_family, a->ai_socktype, a->ai_protocol);
    if (fd < 0) continue;
    if (::connect(fd, a->ai_addr, a->ai_addrlen) == 0) break;
    ::close(fd);
    fd = -1;
  }
  ::freeaddrinfo(res);
  if (fd >= 0) {
    const int one = 1;
    ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one));
  }
  return fd;
}

}  // namespace

std::string RelayRequestHead(const HttpRequest& request) {
  std::string head = absl::StrCat(request.method, " ", request.path);
  char sep = '?';
  for (const auto& [k, v] : request.query) {
    absl::StrAppend(&head, std::string(1, sep), UrlEncode(k), "=", UrlEncode(v));
    sep = '&';
  }
  head += " HTTP/1.1\r\n";
  for (const auto& [k, v] : request.headers) {
    if (k == kPeerHeader) continue;
    absl::StrAppend(&head, k, ": ", v, "\r\n");
  }
  absl::StrAppend(&head, kPeerHeader, ": 1\r\n\r\n");
  return head;
}

absl::Status RelayHttpUpgrade(const HttpRequest& request, int client_fd, const std::string& upstream_address) {
  const int up = Connect(upstream_address);
  if (up < 0) return absl::UnavailableError(absl::StrCat("cannot reach ", upstream_address));
  const std::string head = RelayRequestHead(request);
  if (!WriteAll(up, head.data(), head.size())) {
    ::close(up);
    return absl::UnavailableError(absl::StrCat("cannot write to ", upstream_address));
  }
  // Copy both ways. A side that reaches EOF is half-closed on the other; the relay ends when both have,
  // or on any error (a reset, HttpServer::Stop shutting the client socket).
  pollfd fds[2] = {{client_fd, POLLIN, 0}, {up, POLLIN, 0}};
  const int peer_of[2] = {up, client_fd};
  bool open[2] = {true, true};
  char buf[64 * 1024];
  while (open[0] || open[1]) {
    const int n = ::poll(fds, 2, -1);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) break;
    bool failed = false;
    for (int i = 0; i < 2 && !failed; ++i) {
      if (!open[i] || (fds[i].revents & (POLLIN | POLLHUP | POLLERR)) == 0) continue;
      const ssize_t r = ::recv(fds[i].fd, buf, sizeof(buf), 0);
      if (r < 0 && errno == EINTR) continue;
      if (r < 0) {
        failed = true;
      } else if (r == 0) {
        open[i] = false;
        fds[i].fd = -1;  // poll skips it from now on
        ::shutdown(peer_of[i], SHUT_WR);
      } else if (!WriteAll(peer_of[i], buf, static_cast<size_t>(r))) {
        failed = true;
      }
    }
    if (failed) break;
  }
  ::close(up);
  return absl::OkStatus();
}

}  // namespace dance::server
