// Structured logs: one JSON object per line on stderr, e.g.
//   {"ts":"2026-11-23T01:02:03.456Z","level":"info","event":"session_start","session":"s-1a2b","rate":48000}
//
// Usage:
//   Log(LogLevel::kInfo, "session_start", {{"session", id}, {"sample_rate", 48000}});
//   SetLogLevel(LogLevel::kWarning);   // from main, e.g. --log-level
//
// Thread safety: Log may be called from any thread; each line is written with one fwrite under a mutex.
#ifndef DANCE_SERVER_LOG_H_
#define DANCE_SERVER_LOG_H_

#include "absl/strings/string_view.h"

#include "nlohmann/json.hpp"

namespace dance::server {

enum class LogLevel { kDebug = 0, kInfo = 1, kWarning = 2, kError = 3, kOff = 4 };

void SetLogLevel(LogLevel level);
// Parses "debug", "info", "warning", "error", "off"; false if unknown.
bool ParseLogLevel(absl::string_view text, LogLevel* level);
void Log(LogLevel level, absl::string_view event, const nlohmann::json& fields = nlohmann::json::object());

}  // namespace dance::server

#endif  // DANCE_SERVER_LOG_H_
