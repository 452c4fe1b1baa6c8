// Update: what a live session tells its performer and viewers, in plain C++ (no wire format): one
// InfoUpdate first, then pose frames and events, and an EndUpdate when the session ends normally.
//
// A session builds each update once and publishes the same immutable object to every sink. Each transport
// turns it into its own wire form (server/grpc/convert.h: a dance.v1.DanceUpdate; server/web/json_codec.h:
// the WebSocket JSON) and memoises that form on the update, in a slot it reserved once: however many
// sinks send an update, it is encoded once per wire form, so fan-out costs one encoding per format.
//
// Usage (a transport):
//   static const int kSlot = ReserveEncodingSlot();
//   const std::string& text = update.Encoding<std::string>(kSlot, [&] { return ToText(update); });
//
// Thread safety: an Update is immutable once built. Encoding() may be called from any thread: the first
// caller of a slot builds that form, concurrent callers of the same slot wait for it (an encoding takes
// microseconds); later callers only read it.
#ifndef DANCE_SERVER_CORE_UPDATE_H_
#define DANCE_SERVER_CORE_UPDATE_H_

#include <array>
#include <atomic>
#include <cstdint>
#include <memory>
#include <string>
#include <type_traits>
#include <utility>
#include <variant>

#include "server/core/engine_port.h"

namespace dance::server {

// The first update of every stream: the session's id and the model it runs (a copy: updates may outlive
// the backend's description in a transport's queue).
struct InfoUpdate {
  std::string session_id;
  ModelDescription model;
};

struct FrameUpdate {
  FrameData pose;                  // index, input-timeline time, positions, rotations, VQ codes
  int64_t trigger_sample_end = 0;  // end offset (input sample frames) of the audio chunk that released it
  int64_t server_time_us = 0;      // server clock when it was published, microseconds since the Unix epoch
};

enum class EventKind { kBeat, kControlApplied, kWarning };

struct EventUpdate {
  EventKind kind = EventKind::kWarning;
  double time_ms = 0.0;     // input timeline, ms (audio received when the event happened)
  int64_t frame_index = 0;  // the first frame the event applies to
  std::string message;
};

struct EndUpdate {
  int64_t frames = 0;    // pose frames produced in the whole session
  double audio_ms = 0.0; // audio received, ms on the input timeline
  std::string reason;    // "end_of_audio" or "session_closed"
};

// Slots for memoised wire forms, per update. Each (transport, form) pair reserves one, once; four are
// taken (gRPC and JSON, each with and without rotations), two are spare.
inline constexpr int kMaxEncodings = 6;
// A new slot index in [0, kMaxEncodings); crashes when all are taken (a programming error).
int ReserveEncodingSlot();

class Update {
 public:
  using Body = std::variant<InfoUpdate, FrameUpdate, EventUpdate, EndUpdate>;

  // From one kind: InfoUpdate, FrameUpdate, EventUpdate or EndUpdate.
  template <typename Kind, typename = std::enable_if_t<!std::is_same_v<std::decay_t<Kind>, Update>>>
  explicit Update(Kind&& kind) : body_(std::forward<Kind>(kind)) {}
  Update(const Update&) = delete;
  Update& operator=(const Update&) = delete;

  const Body& body() const { return body_; }
  bool is_frame() const { return std::holds_alternative<FrameUpdate>(body_); }
  // The body as that kind, or nullptr.
  const InfoUpdate* info() const { return std::get_if<InfoUpdate>(&body_); }
  const FrameUpdate* frame() const { return std::get_if<FrameUpdate>(&body_); }
  const EventUpdate* event() const { return std::get_if<EventUpdate>(&body_); }
  const EndUpdate* end() const { return std::get_if<EndUpdate>(&body_); }

  // The wire form kept in `slot` (from ReserveEncodingSlot), built by `build()` (returning a T; it must
  // not throw) on first use. Every caller of one slot must ask for the same T.
  template <typename T, typename Build>
  const T& Encoding(int slot, Build&& build) const {
    Slot& s = slots_[static_cast<size_t>(slot)];
    int state = s.state.load(std::memory_order_acquire);
    if (state != kBuilt) {
      if (state == kEmpty && s.state.compare_exchange_strong(state, kBuilding, std::memory_order_acquire)) {
        s.value = std::make_shared<const T>(build());
        s.state.store(kBuilt, std::memory_order_release);
        s.state.notify_all();
      } else {
        // Another thread is building this form (microseconds): wait for it.
        while ((state = s.state.load(std::memory_order_acquire)) != kBuilt) s.state.wait(state);
      }
    }
    return *static_cast<const T*>(s.value.get());
  }

 private:
  // A slot's life: empty -> building (one thread, the first caller) -> built. Plain atomics rather than
  // absl::call_once, whose waiting path TSan cannot see into (Debian's abseil is not instrumented), and
  // std::call_once, which costs a pthread_once call per encoding.
  static constexpr int kEmpty = 0, kBuilding = 1, kBuilt = 2;
  struct Slot {
    std::atomic<int> state{kEmpty};
    std::shared_ptr<const void> value;  // written once, by the builder, before state becomes kBuilt
  };

  const Body body_;
  mutable std::array<Slot, kMaxEncodings> slots_;
};

using UpdatePtr = std::shared_ptr<const Update>;

}  // namespace dance::server

#endif  // DANCE_SERVER_CORE_UPDATE_H_
