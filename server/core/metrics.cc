#include "server/core/metrics.h"

#include <algorithm>
#include <cmath>
#include <utility>

namespace dance::server {
namespace {

std::vector<double> LatencyBounds() {
  return {0.0005, 0.001, 0.002, 0.005, 0.01, 0.02, 0.035, 0.05, 0.075, 0.1, 0.2, 0.5, 1.0, 2.5};
}

std::vector<double> BatchBounds() { return {1, 2, 4, 8, 16, 32, 64, 128, 256, 512}; }

}  // namespace

Histogram::Histogram(std::vector<double> upper_bounds_s)
    : bounds_(std::move(upper_bounds_s)), buckets_(bounds_.size() + 1) {}

void Histogram::Observe(double seconds) {
  const size_t i = std::lower_bound(bounds_.begin(), bounds_.end(), seconds) - bounds_.begin();
  buckets_[i].fetch_add(1, std::memory_order_relaxed);
  sum_us_.fetch_add(static_cast<uint64_t>(std::max(0.0, seconds) * 1e6), std::memory_order_relaxed);
  count_.fetch_add(1, std::memory_order_relaxed);
}

double Histogram::ApproxQuantile(double q) const {
  const uint64_t n = count_.load(std::memory_order_relaxed);
  if (n == 0) return 0.0;
  const uint64_t target = static_cast<uint64_t>(std::ceil(q * static_cast<double>(n)));
  uint64_t cumulative = 0;
  for (size_t i = 0; i < bounds_.size(); ++i) {
    cumulative += buckets_[i].load(std::memory_order_relaxed);
    if (cumulative >= target) return bounds_[i];
  }
  return INFINITY;
}

ServerMetrics::ServerMetrics()
    : step_latency(LatencyBounds()), frame_latency(LatencyBounds()), batch_size(BatchBounds()) {}

void ServerMetrics::CountError(absl::StatusCode code) {
  const int i = static_cast<int>(code);
  if (i > 0 && i < static_cast<int>(errors_by_code_.size())) {
    errors_by_code_[i].fetch_add(1, std::memory_order_relaxed);
  }
}

uint64_t ServerMetrics::errors(absl::StatusCode code) const {
  const int i = static_cast<int>(code);
  if (i <= 0 || i >= static_cast<int>(errors_by_code_.size())) return 0;
  return errors_by_code_[i].load(std::memory_order_relaxed);
}

}  // namespace dance::server
