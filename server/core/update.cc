#include "server/core/update.h"

#include <atomic>

#include "absl/base/internal/raw_logging.h"

namespace dance::server {

int ReserveEncodingSlot() {
  static std::atomic<int> next{0};
  const int slot = next.fetch_add(1, std::memory_order_relaxed);
  ABSL_RAW_CHECK(slot < kMaxEncodings, "more wire forms than kMaxEncodings: raise it");
  return slot;
}

}  // namespace dance::server
