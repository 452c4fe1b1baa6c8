// Structured logs: one JSON object per line on stderr, e.g.
//   {"event":"session_start","level":"info","sample_rate":48000,"session":"s-1a2b","ts":"2026-11-23T01:02:03.456Z"}
//
// Usage:
//   Log(LogLevel::kInfo, "session_start", {{"session", id}, {"sample_rate", 48000}});
//   SetLogLevel(LogLevel::kWarning);   // from main, e.g. --log-level
//
// The fields are plain values (LogValue), so every layer logs without knowing any JSON library; only
// log.cc formats the line.
// Thread safety: Log may be called from any thread; each line is written with one fwrite under a mutex.
#ifndef DANCE_SERVER_LOG_H_
#define DANCE_SERVER_LOG_H_

#include <cstdint>
#include <initializer_list>
#include <string>
#include <type_traits>
#include <utility>
#include <variant>

#include "absl/strings/string_view.h"

namespace dance::server {

enum class LogLevel { kDebug = 0, kInfo = 1, kWarning = 2, kError = 3, kOff = 4 };

// One field's value: a boolean, an integer, a number or a string.
class LogValue {
 public:
  using Value = std::variant<bool, int64_t, uint64_t, double, std::string>;

  LogValue(bool v) : value_(v) {}  // NOLINT: implicit, so that fields read {{"key", value}}
  template <typename T, std::enable_if_t<std::is_integral_v<T> && !std::is_same_v<T, bool>, int> = 0>
  LogValue(T v) {  // NOLINT
    if constexpr (std::is_signed_v<T>) {
      value_ = static_cast<int64_t>(v);
    } else {
      value_ = static_cast<uint64_t>(v);
    }
  }
  LogValue(double v) : value_(v) {}                          // NOLINT
  LogValue(const char* v) : value_(std::string(v)) {}        // NOLINT
  LogValue(absl::string_view v) : value_(std::string(v)) {}  // NOLINT
  LogValue(std::string v) : value_(std::move(v)) {}          // NOLINT

  const Value& value() const { return value_; }

 private:
  Value value_;
};

struct LogField {
  absl::string_view key;
  LogValue value;
};

void SetLogLevel(LogLevel level);
// Parses "debug", "info", "warning", "error", "off"; false if unknown.
bool ParseLogLevel(absl::string_view text, LogLevel* level);
// Fields named "ts", "level" or "event" replace the line's own.
void Log(LogLevel level, absl::string_view event, std::initializer_list<LogField> fields = {});

}  // namespace dance::server

#endif  // DANCE_SERVER_LOG_H_
