#include "server/web/http_server.h"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "nlohmann/json.hpp"
#include "server/log.h"
#include "server/web/websocket.h"

namespace dance::server {

const char* HttpStatusText(int status) {
  switch (status) {
    case 101: return "Switching Protocols";
    case 200: return "OK";
    case 204: return "No Content";
    case 400: return "Bad Request";
    case 401: return "Unauthorized";
    case 403: return "Forbidden";
    case 404: return "Not Found";
    case 405: return "Method Not Allowed";
    case 413: return "Payload Too Large";
    case 426: return "Upgrade Required";
    case 429: return "Too Many Requests";
    case 500: return "Internal Server Error";
    case 503: return "Service Unavailable";
    default: return "Unknown";
  }
}

std::string HttpRequest::Header(absl::string_view name) const {
  auto it = headers.find(std::string(name));
  return it == headers.end() ? std::string() : it->second;
}

void HttpConnection::Respond(int status, absl::string_view content_type, absl::string_view body,
                             absl::string_view extra_headers) {
  std::string head = absl::StrCat("HTTP/1.1 ", status, " ", HttpStatusText(status), "\r\nContent-Type: ",
                                  content_type, "\r\nContent-Length: ", body.size(),
                                  "\r\nConnection: close\r\nCache-Control: no-cache\r\n", extra_headers, "\r\n");
  head.append(body.data(), body.size());
  WriteAll(fd_, head).IgnoreError();
}

void HttpConnection::RespondJsonError(int status, absl::string_view message) {
  Respond(status, "application/json", nlohmann::json{{"error", std::string(message)}}.dump());
}

HttpServer::HttpServer(HttpServerOptions options, Handler handler)
    : options_(std::move(options)), handler_(std::move(handler)) {}

HttpServer::~HttpServer() { Stop(); }

std::string HttpServer::UrlDecode(absl::string_view in) {
  std::string out;
  out.reserve(in.size());
  for (size_t i = 0; i < in.size(); ++i) {
    if (in[i] == '%' && i + 2 < in.size() && absl::ascii_isxdigit(in[i + 1]) && absl::ascii_isxdigit(in[i + 2])) {
      out.push_back(static_cast<char>(std::stoi(std::string(in.substr(i + 1, 2)), nullptr, 16)));
      i += 2;
    } else if (in[i] == '+') {
      out.push_back(' ');
    } else {
      out.push_back(in[i]);
    }
  }
  return out;
}

absl::StatusOr<int> HttpServer::Start() {
  listen_fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (listen_fd_ < 0) return absl::InternalError(absl::StrCat("socket: ", std::strerror(errno)));
  int one = 1;
  ::setsockopt(listen_fd_, SOL_SOCKET, SO_REUSEADDR, &one, sizeof(one));
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<uint16_t>(options_.port));
  if (::inet_pton(AF_INET, options_.bind_address.c_str(), &addr.sin_addr) != 1) {
    return absl::InvalidArgumentError(absl::StrCat("bad bind address ", options_.bind_address));
  }
  if (::bind(listen_fd_, reinterpret_cast<sockaddr*>(&addr), sizeof(addr)) < 0) {
    const int err = errno;
    ::close(listen_fd_);
    listen_fd_ = -1;
    return absl::UnavailableError(absl::StrCat("bind port ", options_.port, ": ", std::strerror(err)));
  }
  if (::listen(listen_fd_, 128) < 0) return absl::InternalError(absl::StrCat("listen: ", std::strerror(errno)));
  socklen_t len = sizeof(addr);
  ::getsockname(listen_fd_, reinterpret_cast<sockaddr*>(&addr), &len);
  accept_thread_ = std::thread([this] { AcceptLoop(); });
  return static_cast<int>(ntohs(addr.sin_port));
}

void HttpServer::Stop() {
  if (stopping_.exchange(true)) return;
  if (listen_fd_ >= 0) ::shutdown(listen_fd_, SHUT_RDWR);
  if (accept_thread_.joinable()) accept_thread_.join();
  if (listen_fd_ >= 0) ::close(listen_fd_);
  listen_fd_ = -1;
  std::list<std::thread> threads;
  {
    absl::MutexLock lock(&mu_);
    for (int fd : open_fds_) ::shutdown(fd, SHUT_RDWR);  // wakes blocked connection threads
    threads.swap(threads_);
  }
  for (std::thread& t : threads) t.join();
}

void HttpServer::ReapFinished() {
  std::list<std::thread> done;
  {
    absl::MutexLock lock(&mu_);
    for (auto it = threads_.begin(); it != threads_.end();) {
      if (finished_.contains(it->get_id())) {
        finished_.erase(it->get_id());
        done.splice(done.end(), threads_, it++);
      } else {
        ++it;
      }
    }
  }
  for (std::thread& t : done) t.join();
}

void HttpServer::AcceptLoop() {
  while (!stopping_.load()) {
    ReapFinished();
    pollfd p{listen_fd_, POLLIN, 0};
    if (::poll(&p, 1, 200) <= 0) continue;
    const int fd = ::accept4(listen_fd_, nullptr, nullptr, SOCK_CLOEXEC);
    if (fd < 0) continue;
    int one = 1;
    ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one));
    {
      absl::MutexLock lock(&mu_);
      if (active_ >= options_.max_connections || stopping_.load()) {
        HttpConnection(fd).RespondJsonError(503, "too many connections");
        ::close(fd);
        continue;
      }
      ++active_;
      open_fds_.insert(fd);
    }
    absl::MutexLock lock(&mu_);
    threads_.emplace_back([this, fd] {
      Serve(fd);
      absl::MutexLock inner(&mu_);
      open_fds_.erase(fd);
      ::close(fd);
      --active_;
      finished_.insert(std::this_thread::get_id());
    });
  }
}

void HttpServer::Serve(int fd) {
  // Read the request head (up to the blank line) with a deadline; bodies are not supported (GET only).
  std::string head;
  char buf[4096];
  const int64_t deadline_ms = options_.header_timeout_ms;
  int64_t waited = 0;
  while (head.find("\r\n\r\n") == std::string::npos) {
    if (static_cast<int>(head.size()) > options_.max_header_bytes) {
      HttpConnection(fd).RespondJsonError(413, "request head too large");
      return;
    }
    pollfd p{fd, POLLIN, 0};
    const int r = ::poll(&p, 1, 100);
    if (stopping_.load()) return;
    if (r == 0) {
      waited += 100;
      if (waited >= deadline_ms) return;
      continue;
    }
    const ssize_t n = ::recv(fd, buf, sizeof(buf), 0);
    if (n <= 0) return;
    head.append(buf, static_cast<size_t>(n));
  }
  head.resize(head.find("\r\n\r\n"));
  std::vector<absl::string_view> lines = absl::StrSplit(head, "\r\n");
  std::vector<absl::string_view> parts = absl::StrSplit(lines[0], ' ');
  HttpConnection conn(fd);
  if (parts.size() != 3 || !absl::StartsWith(parts[2], "HTTP/1.")) {
    conn.RespondJsonError(400, "malformed request line");
    return;
  }
  HttpRequest req;
  req.method = std::string(parts[0]);
  absl::string_view target = parts[1];
  const size_t q = target.find('?');
  req.path = UrlDecode(target.substr(0, q));
  if (q != absl::string_view::npos) {
    for (absl::string_view kv : absl::StrSplit(target.substr(q + 1), '&', absl::SkipEmpty())) {
      const size_t eq = kv.find('=');
      req.query[UrlDecode(kv.substr(0, eq))] = eq == absl::string_view::npos ? "" : UrlDecode(kv.substr(eq + 1));
    }
  }
  for (size_t i = 1; i < lines.size(); ++i) {
    const size_t colon = lines[i].find(':');
    if (colon == absl::string_view::npos) continue;
    req.headers[absl::AsciiStrToLower(absl::StripAsciiWhitespace(lines[i].substr(0, colon)))] =
        std::string(absl::StripAsciiWhitespace(lines[i].substr(colon + 1)));
  }
  handler_(req, conn);
}

}  // namespace dance::server
