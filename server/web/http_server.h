// A small HTTP/1.1 server over POSIX sockets: one accept thread, one thread per connection (bounded by
// max_connections; beyond that new connections get 503 and are closed). One request per connection
// (responses carry "Connection: close"), except upgrades, which keep the socket for the handler.
//
// Usage:
//   HttpServer http({.port = 8080}, [](HttpRequest& req, HttpConnection& conn) {
//     conn.Respond(200, "text/plain", "hello");
//   });
//   ASSIGN_OR_RETURN(int port, http.Start());   // port 0 picks a free port
//   ...  http.Stop();                          // closes the listener and every connection, joins threads
//
// Thread safety: Start/Stop from one thread. The handler runs on connection threads, concurrently.
#ifndef DANCE_SERVER_WEB_HTTP_SERVER_H_
#define DANCE_SERVER_WEB_HTTP_SERVER_H_

#include <atomic>
#include <functional>
#include <list>
#include <map>
#include <string>
#include "absl/strings/string_view.h"
#include <thread>

#include "absl/base/thread_annotations.h"
#include "absl/container/flat_hash_set.h"
#include "absl/status/statusor.h"
#include "absl/synchronization/mutex.h"

namespace dance::server {

struct HttpRequest {
  std::string method;
  std::string path;                            // decoded path without the query
  std::map<std::string, std::string> query;    // decoded query parameters
  std::map<std::string, std::string> headers;  // lower-cased names
  std::string Header(absl::string_view name) const;
};

class HttpConnection {
 public:
  explicit HttpConnection(int fd) : fd_(fd) {}
  int fd() const { return fd_; }
  // Writes a complete response with Content-Length and Connection: close.
  void Respond(int status, absl::string_view content_type, absl::string_view body,
               absl::string_view extra_headers = "");
  void RespondJsonError(int status, absl::string_view message);

 private:
  const int fd_;
};

struct HttpServerOptions {
  std::string bind_address = "0.0.0.0";
  int port = 8080;
  int max_connections = 256;
  int max_header_bytes = 16 * 1024;
  int header_timeout_ms = 10000;  // time to receive the request head
};

class HttpServer {
 public:
  using Handler = std::function<void(const HttpRequest& request, HttpConnection& connection)>;

  HttpServer(HttpServerOptions options, Handler handler);
  ~HttpServer();  // Stop()
  // Binds and listens; returns the bound port.
  absl::StatusOr<int> Start();
  void Stop();

  static std::string UrlDecode(absl::string_view in);

 private:
  void AcceptLoop();
  void Serve(int fd);
  void ReapFinished();

  const HttpServerOptions options_;
  const Handler handler_;
  int listen_fd_ = -1;
  std::thread accept_thread_;
  std::atomic<bool> stopping_{false};

  absl::Mutex mu_;
  absl::flat_hash_set<int> open_fds_ ABSL_GUARDED_BY(mu_);
  int active_ ABSL_GUARDED_BY(mu_) = 0;
  std::list<std::thread> threads_ ABSL_GUARDED_BY(mu_);
  absl::flat_hash_set<std::thread::id> finished_ ABSL_GUARDED_BY(mu_);
};

const char* HttpStatusText(int status);

}  // namespace dance::server

#endif  // DANCE_SERVER_WEB_HTTP_SERVER_H_
