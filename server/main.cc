// dance-server: serves the dance model over gRPC (Perform, Watch, ListSessions, GetModelInfo, health,
// reflection) and HTTP (web visualizer, /metrics, /api, WebSocket). Every flag can also be set with an
// environment variable DANCE_<FLAG_NAME_IN_CAPS> (e.g. DANCE_MAX_SESSIONS=100); the command line wins.
//
//   dance-server --port 50051 --http-port 8080 --model models/default.dncw --max-sessions 200
//
// SIGTERM / SIGINT: stop admitting, drain live sessions for --drain-timeout, then exit.
#include <sched.h>
#include <signal.h>

#include <algorithm>
#include <cstdlib>
#include <iostream>
#include <fstream>
#include <string>
#include <thread>
#include <vector>

#include "absl/flags/flag.h"
#include "absl/flags/parse.h"
#include "absl/flags/reflection.h"
#include "absl/flags/usage.h"
#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"
#include "absl/time/time.h"
#include "server/core/engine_port.h"
#include "server/dance_server.h"
#include "server/log.h"

#ifndef DANCE_SOURCE_DIR
#define DANCE_SOURCE_DIR "."
#endif

ABSL_FLAG(std::string, host, "0.0.0.0", "Address to bind (gRPC and HTTP).");
ABSL_FLAG(int, port, 50051, "gRPC port (0 = any free port).");
ABSL_FLAG(int, http_port, 8080, "HTTP/WebSocket port (0 = any free port, -1 = off).");
ABSL_FLAG(std::string, model, "", "Model file (.dncw). Default: models/default.dncw, else models/test-tiny.dncw.");
ABSL_FLAG(std::string, web_root, DANCE_SOURCE_DIR "/web/dist", "Directory served at / (the built web page).");
ABSL_FLAG(int, max_sessions, 256, "Admission limit: concurrent Perform sessions (beyond: RESOURCE_EXHAUSTED).");
ABSL_FLAG(int, scheduler_threads, 0,
          "Scheduler threads stepping sessions (each owns a share of them); 0 = one per usable CPU (affinity "
          "mask, at most 64).");
ABSL_FLAG(int, max_batch, 256, "Largest number of sessions in one batched engine step.");
ABSL_FLAG(int, max_viewers, 64, "Watch subscribers per session.");
ABSL_FLAG(int, max_chunk_samples, 48000, "Largest audio chunk, sample frames.");
ABSL_FLAG(int, min_sample_rate, 8000, "Lowest accepted input sample rate, Hz.");
ABSL_FLAG(int, max_sample_rate, 96000, "Highest accepted input sample rate, Hz.");
ABSL_FLAG(int, max_channels, 8, "Most input channels.");
ABSL_FLAG(int, max_pending_seconds, 10, "Audio a session may queue ahead of the scheduler before reads pause, s.");
ABSL_FLAG(int, max_message_bytes, 4 << 20, "Largest gRPC message, bytes.");
ABSL_FLAG(int, performer_queue, 1024, "Updates queued for a performer before its call fails (not reading).");
ABSL_FLAG(int, viewer_queue, 8, "Frames queued for a viewer before old frames are dropped.");
ABSL_FLAG(int, max_http_connections, 256, "Concurrent HTTP/WebSocket connections.");
ABSL_FLAG(absl::Duration, idle_timeout, absl::Seconds(30), "End a session after this long without audio.");
ABSL_FLAG(absl::Duration, max_session, absl::Hours(4), "End a session after this long in total.");
ABSL_FLAG(absl::Duration, stall_timeout, absl::Seconds(10),
          "Fail a session whose client has not read its frames for this long (RESOURCE_EXHAUSTED).");
ABSL_FLAG(absl::Duration, keepalive_time, absl::Seconds(30), "gRPC keepalive ping interval.");
ABSL_FLAG(absl::Duration, keepalive_timeout, absl::Seconds(10), "gRPC keepalive ping timeout.");
ABSL_FLAG(absl::Duration, drain_timeout, absl::Seconds(30), "On SIGTERM, how long live sessions may finish.");
ABSL_FLAG(std::string, tls_cert, "", "PEM certificate chain (with --tls-key: TLS on the gRPC port).");
ABSL_FLAG(std::string, tls_key, "", "PEM private key.");
ABSL_FLAG(std::string, auth_token, "", "If set, clients must send 'authorization: Bearer <token>'.");
ABSL_FLAG(std::string, log_level, "info", "debug, info, warning, error or off.");
ABSL_FLAG(std::string, cluster_store, "",
          "Redis host:port shared by several servers: sessions registered there, Watch and ListSessions reach "
          "every server's sessions (empty = a single server).");
ABSL_FLAG(std::string, advertise_host, "127.0.0.1", "With --cluster-store: the address peers reach this server at.");
ABSL_FLAG(std::string, server_id, "", "With --cluster-store: this server's unique name (default: advertise host:port).");
ABSL_FLAG(absl::Duration, cluster_ttl, absl::Seconds(5),
          "With --cluster-store: a server's entries expire this long after its last heartbeat.");

ABSL_FLAG(std::string, editor_model, "",
          "Diffusion editor model (.dncw of kind sgmd) for the Edit RPC. Default: models/sgmd.dncw if present; "
          "'off' = no Edit RPC.");
ABSL_FLAG(int, edit_workers, 1, "Edits that run at once (each takes one core while it runs).");
ABSL_FLAG(int, edit_queue, 8, "Edits that may wait for a worker before Edit answers RESOURCE_EXHAUSTED.");
ABSL_FLAG(int, edit_max_per_client, 1, "Edits one client address may have queued or running.");
ABSL_FLAG(double, edit_max_audio_s, 600, "Longest song an edit accepts, seconds.");
ABSL_FLAG(int, edit_max_audio_mb, 16, "Largest encoded song an edit accepts, MB (raises the gRPC message limit).");

namespace {

constexpr const char* kFlagNames[] = {"editor_model", "edit_workers", "edit_queue", "edit_max_per_client",
    "edit_max_audio_s", "edit_max_audio_mb",
    "host", "port", "http_port", "model", "web_root", "max_sessions", "scheduler_threads", "max_batch",
    "max_viewers", "max_chunk_samples", "min_sample_rate", "max_sample_rate", "max_channels",
    "max_pending_seconds", "max_message_bytes", "performer_queue", "viewer_queue", "max_http_connections",
    "idle_timeout", "max_session", "stall_timeout", "keepalive_time", "keepalive_timeout", "drain_timeout", "tls_cert",
    "tls_key", "auth_token", "log_level", "cluster_store", "advertise_host", "server_id", "cluster_ttl"};

// Applies DANCE_<NAME> environment variables as flag defaults (before the command line is parsed).
bool ApplyEnvironment() {
  for (const char* name : kFlagNames) {
    const std::string var = absl::StrCat("DANCE_", absl::AsciiStrToUpper(name));
    const char* value = std::getenv(var.c_str());
    if (value == nullptr) continue;
    absl::CommandLineFlag* flag = absl::FindCommandLineFlag(name);
    std::string error;
    if (flag == nullptr || !flag->ParseFrom(value, &error)) {
      std::cerr << "dance-server: bad " << var << "=" << value << ": " << error << "\n";
      return false;
    }
  }
  return true;
}

// models/sgmd.dncw (in . or the source tree), or "" if neither has one.
std::string DefaultEditorModel() {
  for (const std::string& base : {std::string("."), std::string(DANCE_SOURCE_DIR)}) {
    const std::string path = absl::StrCat(base, "/models/sgmd.dncw");
    if (std::ifstream(path).good()) return path;
  }
  return "";
}

std::string DefaultModel() {
  for (const char* candidate : {"models/default.dncw", "models/test-tiny.dncw"}) {
    for (const std::string& base : {std::string("."), std::string(DANCE_SOURCE_DIR)}) {
      const std::string path = absl::StrCat(base, "/", candidate);
      if (FILE* f = std::fopen(path.c_str(), "rb")) {
        std::fclose(f);
        return path;
      }
    }
  }
  return "models/default.dncw";
}

// CPUs this process may run on (its affinity mask: taskset, cpusets), at most 64; hardware_concurrency()
// would count every CPU of the host.
int UsableCpus() {
  cpu_set_t set;
  CPU_ZERO(&set);
  int n = 0;
  if (sched_getaffinity(0, sizeof(set), &set) == 0) n = CPU_COUNT(&set);
  if (n <= 0) n = static_cast<int>(std::thread::hardware_concurrency());
  return std::clamp(n, 1, 64);
}

// absl flags are spelled with underscores; accept the documented dashed spelling too (--http-port).
std::vector<std::string> DashesToUnderscores(int argc, char** argv) {
  std::vector<std::string> out(argv, argv + argc);
  for (size_t i = 1; i < out.size(); ++i) {
    std::string& a = out[i];
    if (a == "--") break;
    if (a.size() < 3 || a[0] != '-' || a[1] != '-') continue;
    const size_t end = std::min(a.find('='), a.size());
    for (size_t k = 2; k < end; ++k) {
      if (a[k] == '-') a[k] = '_';
    }
  }
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  using dance::server::Log;
  using dance::server::LogLevel;
  absl::SetProgramUsageMessage(
      "dance-server --port P [--http-port H] [--model M] [--max-sessions N]  (flags also from DANCE_* env)");
  if (!ApplyEnvironment()) return 2;
  std::vector<std::string> args = DashesToUnderscores(argc, argv);
  std::vector<char*> arg_ptrs;
  for (std::string& a : args) arg_ptrs.push_back(a.data());
  absl::ParseCommandLine(static_cast<int>(arg_ptrs.size()), arg_ptrs.data());
  LogLevel level;
  if (!dance::server::ParseLogLevel(absl::GetFlag(FLAGS_log_level), &level)) {
    std::cerr << "dance-server: bad --log-level\n";
    return 2;
  }
  dance::server::SetLogLevel(level);

  // Block the signals before any thread starts, so only sigwait below sees them.
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGTERM);
  sigaddset(&signals, SIGINT);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);
  signal(SIGPIPE, SIG_IGN);

  std::string model_path = absl::GetFlag(FLAGS_model);
  if (model_path.empty()) model_path = DefaultModel();
  auto backend = dance::server::LoadEngineBackend(model_path);
  if (!backend.ok()) {
    Log(LogLevel::kError, "model_load_failed", {{"path", model_path}, {"error", backend.status().ToString()}});
    return 1;
  }
  dance::server::DanceServerOptions o;
  o.host = absl::GetFlag(FLAGS_host);
  o.port = absl::GetFlag(FLAGS_port);
  o.http_port = absl::GetFlag(FLAGS_http_port);
  o.hub.max_sessions = absl::GetFlag(FLAGS_max_sessions);
  o.hub.scheduler_threads = absl::GetFlag(FLAGS_scheduler_threads);
  if (o.hub.scheduler_threads < 0) {
    std::cerr << "dance-server: --scheduler-threads must be >= 0 (0 = one per usable CPU)\n";
    return 2;
  }
  if (o.hub.scheduler_threads == 0) o.hub.scheduler_threads = UsableCpus();
  o.hub.max_batch = absl::GetFlag(FLAGS_max_batch);
  o.hub.max_viewers_per_session = absl::GetFlag(FLAGS_max_viewers);
  o.hub.max_pending_samples = int64_t{absl::GetFlag(FLAGS_max_pending_seconds)} * absl::GetFlag(FLAGS_max_sample_rate);
  o.hub.idle_timeout = absl::GetFlag(FLAGS_idle_timeout);
  o.hub.max_duration = absl::GetFlag(FLAGS_max_session);
  o.hub.stall_timeout = absl::GetFlag(FLAGS_stall_timeout);
  o.service.auth_token = absl::GetFlag(FLAGS_auth_token);
  o.service.limits.min_sample_rate_hz = absl::GetFlag(FLAGS_min_sample_rate);
  o.service.limits.max_sample_rate_hz = absl::GetFlag(FLAGS_max_sample_rate);
  o.service.limits.max_channels = absl::GetFlag(FLAGS_max_channels);
  o.service.limits.max_chunk_samples = absl::GetFlag(FLAGS_max_chunk_samples);
  o.service.performer_queue_limit = absl::GetFlag(FLAGS_performer_queue);
  o.service.viewer_queue_frames = absl::GetFlag(FLAGS_viewer_queue);
  o.web.web_root = absl::GetFlag(FLAGS_web_root);
  o.web.max_ws_message_bytes = size_t{4} * o.service.limits.max_chunk_samples * o.service.limits.max_channels + 1024;
  o.max_http_connections = absl::GetFlag(FLAGS_max_http_connections);
  o.max_message_bytes = absl::GetFlag(FLAGS_max_message_bytes);
  o.keepalive_time = absl::GetFlag(FLAGS_keepalive_time);
  o.keepalive_timeout = absl::GetFlag(FLAGS_keepalive_timeout);
  std::string editor_path = absl::GetFlag(FLAGS_editor_model);
  if (editor_path.empty()) editor_path = DefaultEditorModel();
  if (!editor_path.empty() && editor_path != "off") {
    auto editor = dance::server::LoadEditorBackend(editor_path);
    if (!editor.ok()) {
      Log(LogLevel::kError, "editor_load_failed", {{"path", editor_path}, {"error", editor.status().ToString()}});
      return 1;
    }
    o.editor = *std::move(editor);
    o.edit.workers = std::max(1, absl::GetFlag(FLAGS_edit_workers));
    o.edit.max_queued = std::max(0, absl::GetFlag(FLAGS_edit_queue));
    o.edit.max_per_client = std::max(1, absl::GetFlag(FLAGS_edit_max_per_client));
    o.edit.max_audio_s = absl::GetFlag(FLAGS_edit_max_audio_s);
    o.max_message_bytes = std::max(o.max_message_bytes, (absl::GetFlag(FLAGS_edit_max_audio_mb) + 1) << 20);
  }
  o.tls_cert_file = absl::GetFlag(FLAGS_tls_cert);
  o.tls_key_file = absl::GetFlag(FLAGS_tls_key);
  o.cluster.store_address = absl::GetFlag(FLAGS_cluster_store);
  o.cluster.advertise_host = absl::GetFlag(FLAGS_advertise_host);
  o.cluster.server_id = absl::GetFlag(FLAGS_server_id);
  o.cluster.ttl = absl::GetFlag(FLAGS_cluster_ttl);
  o.cluster.heartbeat = std::max(absl::Milliseconds(100), o.cluster.ttl / 5);

  auto server = dance::server::DanceServer::Start(*std::move(backend), o);
  if (!server.ok()) {
    Log(LogLevel::kError, "start_failed", {{"error", server.status().ToString()}});
    return 1;
  }
  std::cout << "dance-server: gRPC on port " << (*server)->port() << ", HTTP on port " << (*server)->http_port()
            << ", model " << model_path
            << (o.editor != nullptr ? absl::StrCat(", editor ", editor_path) : std::string(", no editor")) << std::endl;

  int sig = 0;
  sigwait(&signals, &sig);
  Log(LogLevel::kInfo, "signal", {{"signal", sig == SIGTERM ? "SIGTERM" : "SIGINT"}});
  (*server)->Drain(absl::GetFlag(FLAGS_drain_timeout));
  (*server)->Shutdown();
  return 0;
}
