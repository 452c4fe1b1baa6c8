#include "server/web/web_handler.h"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>

#include <algorithm>
#include <deque>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>
#include <thread>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/time/clock.h"
#include "nlohmann/json.hpp"
#include "server/log.h"
#include "server/web/json_codec.h"
#include "server/web/prometheus.h"
#include "server/web/websocket.h"
#include "server/web/ws_sink.h"

namespace dance::server {
namespace {

using nlohmann::json;

const char* MimeType(const std::string& ext) {
  if (ext == ".html") return "text/html; charset=utf-8";
  if (ext == ".js" || ext == ".mjs") return "text/javascript; charset=utf-8";
  if (ext == ".css") return "text/css; charset=utf-8";
  if (ext == ".json" || ext == ".map") return "application/json";
  if (ext == ".svg") return "image/svg+xml";
  if (ext == ".png") return "image/png";
  if (ext == ".jpg" || ext == ".jpeg") return "image/jpeg";
  if (ext == ".ico") return "image/x-icon";
  if (ext == ".wasm") return "application/wasm";
  if (ext == ".glb") return "model/gltf-binary";
  if (ext == ".ogg") return "audio/ogg";
  if (ext == ".wav") return "audio/wav";
  return "application/octet-stream";
}

constexpr char kFallbackPage[] =
    "<!doctype html><meta charset=utf-8><title>dance-server</title>"
    "<h1>dance-server</h1><p>The web visualizer is not built (run <code>npm ci && npm run build</code> in "
    "<code>web/</code>, or pass <code>--web-root</code>).</p><p>Live sessions: <a href=/api/sessions>"
    "/api/sessions</a> &middot; metrics: <a href=/metrics>/metrics</a></p>";


// Runs the writer side of a WebSocket: sends every update as JSON until the sink closes, then an error
// message (if any) and a close frame, then shuts the socket's read side so the reader thread wakes up.
void WriterLoop(WsSink* sink, WebSocket* ws, int fd) {
  UpdatePtr u;
  int64_t dropped_before = 0;
  absl::Status final;
  std::string scratch;
  bool alive = true;
  while (sink->Next(&u, &dropped_before, &final)) {
    if (!alive) continue;  // keep draining; the reader notices
    if (!ws->SendText(UpdateToJson(*u, sink->wants_rotations(), dropped_before, &scratch)).ok()) alive = false;
  }
  if (alive) {
    if (!final.ok()) ws->SendText(ErrorToJson(final)).IgnoreError();
    const uint16_t code = final.ok() ? 1000 : (final.code() == absl::StatusCode::kInternal ? 1011 : 1008);
    ws->SendClose(code, final.ok() ? "end" : "error").IgnoreError();
  }
  ::shutdown(fd, SHUT_RD);
}

// The connection's remote address (no port): the key of the per-client edit limit.
std::string PeerAddress(int fd) {
  sockaddr_storage addr{};
  socklen_t len = sizeof(addr);
  if (::getpeername(fd, reinterpret_cast<sockaddr*>(&addr), &len) != 0) return "unknown";
  char text[INET6_ADDRSTRLEN] = {0};
  const void* where = addr.ss_family == AF_INET6 ? static_cast<const void*>(&reinterpret_cast<sockaddr_in6*>(&addr)->sin6_addr)
                                                 : static_cast<const void*>(&reinterpret_cast<sockaddr_in*>(&addr)->sin_addr);
  if (::inet_ntop(addr.ss_family, where, text, sizeof(text)) == nullptr) return "unknown";
  return text;
}

}  // namespace

WebHandler::WebHandler(SessionHub* hub, ServerMetrics* metrics, WebOptions options, EditJobs* edit_jobs)
    : hub_(hub), metrics_(metrics), options_(std::move(options)), edit_jobs_(edit_jobs) {}

bool WebHandler::Authorized(const HttpRequest& req) const {
  if (options_.auth_token.empty()) return true;
  if (req.Header("authorization") == "Bearer " + options_.auth_token) return true;
  auto it = req.query.find("token");
  return it != req.query.end() && it->second == options_.auth_token;
}

void WebHandler::Handle(const HttpRequest& req, HttpConnection& conn) {
  if (req.method != "GET" && req.method != "HEAD") {
    conn.RespondJsonError(405, "only GET is supported");
    return;
  }
  if (req.path == "/metrics") {
    conn.Respond(200, "text/plain; version=0.0.4",
                 RenderPrometheus(*metrics_, hub_->active_sessions(), hub_->options().max_sessions,
                                  hub_->draining()));
    return;
  }
  if (req.path == "/healthz") {
    if (hub_->draining()) {
      conn.Respond(503, "text/plain", "draining\n");
    } else if (!hub_->serving()) {
      conn.Respond(503, "text/plain", "full\n");
    } else {
      conn.Respond(200, "text/plain", "ok\n");
    }
    return;
  }
  const bool api = absl::StartsWith(req.path, "/api/") || absl::StartsWith(req.path, "/ws/");
  if (api && !Authorized(req)) {
    conn.RespondJsonError(401, "missing or wrong token");
    return;
  }
  if (req.path == "/api/sessions") {
    json list = json::array();
    for (const auto& s : hub_->List()) list.push_back(SummaryToJson(s));
    conn.Respond(200, "application/json", json{{"sessions", list}}.dump());
  } else if (req.path == "/api/model") {
    json m = ModelToJson(hub_->model());
    m["max_sessions"] = hub_->options().max_sessions;
    m["active_sessions"] = hub_->active_sessions();
    if (edit_jobs_ != nullptr) m["editor"] = EditorToJson(*edit_jobs_);
    conn.Respond(200, "application/json", m.dump());
  } else if (req.path == "/ws/watch") {
    WatchSocket(req, conn);
  } else if (req.path == "/ws/perform") {
    PerformSocket(req, conn);
  } else if (req.path == "/ws/edit") {
    EditSocket(req, conn);
  } else if (api) {
    conn.RespondJsonError(404, "no such endpoint");
  } else {
    ServeStatic(req, conn);
  }
}

void WebHandler::ServeStatic(const HttpRequest& req, HttpConnection& conn) {
  namespace fs = std::filesystem;
  std::string rel = req.path == "/" ? "/index.html" : req.path;
  if (rel.find("..") != std::string::npos || rel.find('\0') != std::string::npos) {
    conn.RespondJsonError(400, "bad path");
    return;
  }
  std::error_code ec;
  fs::path file = fs::path(options_.web_root) / rel.substr(1);
  if (options_.web_root.empty() || !fs::is_regular_file(file, ec)) {
    if (rel == "/index.html") {
      conn.Respond(200, "text/html; charset=utf-8", kFallbackPage);
    } else {
      conn.RespondJsonError(404, "not found");
    }
    return;
  }
  std::ifstream in(file, std::ios::binary);
  std::stringstream body;
  body << in.rdbuf();
  conn.Respond(200, MimeType(file.extension().string()), req.method == "HEAD" ? "" : body.str());
}

bool WebHandler::Upgrade(const HttpRequest& req, HttpConnection& conn) {
  const std::string key = req.Header("sec-websocket-key");
  if (!absl::StrContains(absl::AsciiStrToLower(req.Header("upgrade")), "websocket") || key.empty()) {
    conn.RespondJsonError(426, "WebSocket upgrade required");
    return false;
  }
  const std::string head = absl::StrCat(
      "HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Accept: ",
      WebSocketAcceptKey(key), "\r\n\r\n");
  return WriteAll(conn.fd(), head).ok();
}

void WebHandler::WatchSocket(const HttpRequest& req, HttpConnection& conn) {
  auto it = req.query.find("session");
  std::shared_ptr<LiveSession> session = it == req.query.end() ? nullptr : hub_->Find(it->second);
  if (session == nullptr) {
    metrics_->CountError(absl::StatusCode::kNotFound);
    conn.RespondJsonError(404, "no such live session");
    return;
  }
  if (!Upgrade(req, conn)) return;
  WebSocket ws(conn.fd(), options_.max_ws_message_bytes);
  auto sink = std::make_shared<WsSink>(/*lossy=*/true, options_.viewer_queue_frames, true, metrics_);
  absl::Status st = session->AddViewer(sink);
  if (!st.ok()) {
    ws.SendText(ErrorToJson(st)).IgnoreError();
    ws.SendClose(1008, "refused").IgnoreError();
    return;
  }
  metrics_->viewers_started_total.fetch_add(1);
  metrics_->viewers_active.fetch_add(1);
  std::thread writer([&] { WriterLoop(sink.get(), &ws, conn.fd()); });
  while (ws.Receive().ok()) {
    // Viewers have nothing to say; pings are answered inside Receive.
  }
  sink->Close(absl::CancelledError("viewer left"));
  writer.join();
  session->RemoveViewer(sink.get());
  metrics_->viewers_active.fetch_sub(1);
}

void WebHandler::PerformSocket(const HttpRequest& req, HttpConnection& conn) {
  if (!Upgrade(req, conn)) return;
  WebSocket ws(conn.fd(), options_.max_ws_message_bytes);
  auto fail_early = [&](const absl::Status& st) {
    metrics_->CountError(st.code());
    ws.SendText(ErrorToJson(st)).IgnoreError();
    ws.SendClose(1008, "error").IgnoreError();
  };
  // 1. The start message.
  absl::StatusOr<WebSocket::Message> first = ws.Receive();
  if (!first.ok()) return;
  if (first->binary) return fail_early(absl::InvalidArgumentError("audio before the start message"));
  json start = json::parse(first->data, nullptr, /*allow_exceptions=*/false);
  if (!start.is_object() || start.value("type", "") != "start") {
    return fail_early(absl::InvalidArgumentError("first message must be {\"type\": \"start\", ...}"));
  }
  absl::StatusOr<StreamRequest> request = StreamRequestFromJson(start);
  if (!request.ok()) return fail_early(request.status());
  absl::StatusOr<ValidatedStream> valid = ValidateStream(*request, hub_->model(), options_.limits);
  if (!valid.ok()) return fail_early(valid.status());
  absl::StatusOr<std::shared_ptr<LiveSession>> admitted =
      hub_->Admit(valid->config, valid->format, valid->client_name.empty() ? "websocket" : valid->client_name);
  if (!admitted.ok()) return fail_early(admitted.status());
  std::shared_ptr<LiveSession> session = *admitted;

  // 2. Writer thread; reads pause when the inbox is full and resume when the scheduler drains it.
  auto sink = std::make_shared<WsSink>(/*lossy=*/false, options_.performer_queue_limit, !valid->omit_rotations,
                                       metrics_);
  auto resume = std::make_shared<std::pair<absl::Mutex, bool>>();
  session->SetReadResumer([resume] {
    absl::MutexLock lock(&resume->first);
    resume->second = false;
  });
  session->AttachPerformer(sink);
  std::thread writer([&] { WriterLoop(sink.get(), &ws, conn.fd()); });

  // 3. Audio, control and end.
  int64_t offset = 0;
  bool ended = false;
  absl::Status error;
  while (error.ok()) {
    absl::StatusOr<WebSocket::Message> m = ws.Receive();
    if (!m.ok()) {
      if (!ended) error = absl::CancelledError("browser closed the socket before end");
      break;
    }
    if (m->binary) {
      error = ValidateChunk(m->data.size(), *valid, options_.limits);
      if (!error.ok()) break;
      const int64_t frames = static_cast<int64_t>(m->data.size()) / (4 * valid->config.channels);
      bool pause = false;
      {
        absl::MutexLock lock(&resume->first);
        error = session->EnqueueAudio(offset, std::move(m->data), absl::Now(), &pause);
        if (pause) resume->second = true;
      }
      offset += frames;
      if (pause) {
        absl::MutexLock lock(&resume->first);
        auto resumed = [&resume]() { return !resume->second; };
        resume->first.AwaitWithTimeout(absl::Condition(&resumed), absl::Seconds(30));
      }
      continue;
    }
    json j = json::parse(m->data, nullptr, false);
    const std::string type = j.is_object() ? j.value("type", "") : "";
    if (type == "end") {
      error = session->EnqueueEnd(absl::Now());
      ended = true;
    } else if (type == "control") {
      absl::StatusOr<ControlRequest> control = ControlRequestFromJson(j);
      if (!control.ok()) {
        error = control.status();
        break;
      }
      absl::StatusOr<ValidatedControl> c = ValidateControl(*control, hub_->model());
      if (!c.ok()) {
        error = c.status();
        break;
      }
      error = session->EnqueueControl(*std::move(c));
    } else if (type == "poses") {
      absl::StatusOr<std::vector<PoseRequest>> poses = PosesFromJson(j);
      if (!poses.ok()) {
        error = poses.status();
        break;
      }
      error = session->EnqueuePoses(*std::move(poses), absl::Now());
    } else {
      error = absl::InvalidArgumentError("expected a binary audio message or a JSON control, poses or end message");
    }
  }
  if (!error.ok()) {
    session->Fail(error);
    sink->Close(error);
  }
  writer.join();
}

void WebHandler::EditSocket(const HttpRequest& req, HttpConnection& conn) {
  if (!Upgrade(req, conn)) return;
  WebSocket ws(conn.fd(), std::max(options_.max_ws_message_bytes, options_.max_edit_bytes));
  auto fail = [&](const absl::Status& st) {
    metrics_->CountError(st.code());
    ws.SendText(ErrorToJson(st)).IgnoreError();
    ws.SendClose(1008, "error").IgnoreError();
  };
  if (edit_jobs_ == nullptr) {
    return fail(absl::UnimplementedError("this server has no editor model (start it with --editor-model)"));
  }
  if (!hub_->serving()) return fail(absl::UnavailableError("the server is draining"));
  absl::StatusOr<WebSocket::Message> first = ws.Receive();
  if (!first.ok()) return;
  json request = first->binary ? json() : json::parse(first->data, nullptr, /*allow_exceptions=*/false);
  if (!request.is_object() || request.value("type", "") != "edit") {
    return fail(absl::InvalidArgumentError("first message must be {\"type\": \"edit\", ...}, then the song"));
  }
  absl::StatusOr<EditConfig> config = EditConfigFromJson(request);
  if (!config.ok()) return fail(config.status());
  absl::StatusOr<WebSocket::Message> song = ws.Receive();
  if (!song.ok()) return;
  if (!song->binary) return fail(absl::InvalidArgumentError("audio: the second message must be the song file (binary)"));
  config->audio = std::move(song->data);
  const EditorDescription& editor = edit_jobs_->editor()->Describe();
  if (absl::Status st = ValidateEditConfig(*config, editor); !st.ok()) return fail(st);
  const bool with_rotations = !(request.contains("omit_rotations") && request["omit_rotations"].is_boolean() &&
                                request["omit_rotations"].get<bool>());

  // Job events are queued here and sent by this thread; a reader thread notices the browser leaving.
  struct Outbox {
    absl::Mutex mu;
    std::deque<std::string> texts;
    bool done = false;
    bool last_is_progress = false;
    absl::Status status;
  };
  auto box = std::make_shared<Outbox>();
  absl::StatusOr<std::shared_ptr<EditJob>> job = edit_jobs_->Submit(
      absl::StrCat("http:", PeerAddress(conn.fd())),
      *std::move(config), [box, &editor, with_rotations](const EditEvent& e) {
        std::string text = EditEventToJson(e, editor, with_rotations);
        absl::MutexLock lock(&box->mu);
        const bool progress = e.kind == EditEvent::Kind::kProgress;
        if (progress && box->last_is_progress && !box->texts.empty()) {
          box->texts.back() = std::move(text);  // only the newest progress is worth sending
        } else {
          box->texts.push_back(std::move(text));
        }
        box->last_is_progress = progress;
        if (e.kind == EditEvent::Kind::kDone) {
          box->done = true;
          box->status = e.status;
        }
      });
  if (!job.ok()) return fail(job.status());
  std::thread reader([&ws, job = *job] {
    while (ws.Receive().ok()) {
    }
    job->Cancel();  // the browser closed the socket (or sent garbage): stop the edit
  });
  bool alive = true;
  for (;;) {
    std::deque<std::string> texts;
    bool done = false;
    absl::Status status;
    {
      absl::MutexLock lock(&box->mu);
      box->mu.AwaitWithTimeout(absl::Condition(
                                   +[](Outbox* b) { return b->done || !b->texts.empty(); }, box.get()),
                               absl::Seconds(1));
      texts.swap(box->texts);
      box->last_is_progress = false;
      done = box->done;
      status = box->status;
    }
    for (const std::string& t : texts) {
      if (alive && !ws.SendText(t).ok()) {
        alive = false;
        (*job)->Cancel();
      }
    }
    if (done) {
      if (!status.ok()) metrics_->CountError(status.code());
      if (alive) ws.SendClose(status.ok() ? 1000 : 1008, status.ok() ? "done" : "error").IgnoreError();
      break;
    }
  }
  ::shutdown(conn.fd(), SHUT_RDWR);
  reader.join();
}

}  // namespace dance::server
