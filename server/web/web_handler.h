// WebHandler: the dance server's HTTP routes (docs/protocol.md section 2): static files from the web root,
// /metrics, /api/sessions, /api/model, /healthz, and the WebSocket endpoints /ws/watch, /ws/perform and
// /ws/edit (the diffusion editor: one JSON request, the song as one binary message, then queue position,
// progress and the whole dance back).
// The web transport over the core (server/core/): it decodes and encodes the browser's JSON itself
// (json_codec.h) and validates with the core's rules; no proto is involved.
//
// Each WebSocket uses its HTTP connection thread to read and one extra thread to write, so a slow browser
// blocks only its own writer; a watcher's queue drops old frames, a performer's fails when it overflows.
//
// Usage:
//   WebHandler web(&hub, &metrics, options);
//   HttpServer http(http_options, [&web](const HttpRequest& r, HttpConnection& c) { web.Handle(r, c); });
//
// Thread safety: Handle is called concurrently from connection threads; it only touches thread-safe state.
#ifndef DANCE_SERVER_WEB_WEB_HANDLER_H_
#define DANCE_SERVER_WEB_WEB_HANDLER_H_

#include <cstddef>
#include <string>

#include "server/core/edit_jobs.h"
#include "server/core/metrics.h"
#include "server/core/session_hub.h"
#include "server/core/stream_request.h"
#include "server/web/http_server.h"

namespace dance::server {

struct WebOptions {
  std::string web_root;           // directory with index.html; empty or missing = a small fallback page
  std::string auth_token;         // empty = open
  StreamLimits limits;
  size_t viewer_queue_frames = 8;
  size_t performer_queue_limit = 1024;
  size_t max_ws_message_bytes = 1 << 20;
  size_t max_edit_bytes = size_t{17} << 20;  // the song of a /ws/edit
};

class WebHandler {
 public:
  // `edit_jobs` may be null (no editor: /ws/edit answers an UNIMPLEMENTED error).
  WebHandler(SessionHub* hub, ServerMetrics* metrics, WebOptions options, EditJobs* edit_jobs = nullptr);
  void Handle(const HttpRequest& request, HttpConnection& connection);

 private:
  bool Authorized(const HttpRequest& request) const;
  void ServeStatic(const HttpRequest& request, HttpConnection& connection);
  bool Upgrade(const HttpRequest& request, HttpConnection& connection);
  void WatchSocket(const HttpRequest& request, HttpConnection& connection);
  void PerformSocket(const HttpRequest& request, HttpConnection& connection);
  void EditSocket(const HttpRequest& request, HttpConnection& connection);

  SessionHub* const hub_;
  ServerMetrics* const metrics_;
  const WebOptions options_;
  EditJobs* const edit_jobs_;
};

}  // namespace dance::server

#endif  // DANCE_SERVER_WEB_WEB_HANDLER_H_
