// The metrics (server/core/metrics.h) in the Prometheus text exposition format 0.0.4, for GET /metrics.
// Metric names and meanings: docs/server.md.
//
// Usage:
//   std::string text = RenderPrometheus(metrics, hub.active_sessions(), hub.options().max_sessions,
//                                       hub.draining());
//
// Thread safety: reads the metrics' atomics; call from any thread.
#ifndef DANCE_SERVER_WEB_PROMETHEUS_H_
#define DANCE_SERVER_WEB_PROMETHEUS_H_

#include <string>

#include "server/core/metrics.h"

namespace dance::server {

std::string RenderPrometheus(const ServerMetrics& metrics, int active_sessions, int max_sessions, bool draining);
// Appends "# HELP", "# TYPE", the cumulative buckets, _sum and _count lines of one histogram.
void RenderHistogram(const Histogram& histogram, const std::string& name, const std::string& help,
                     std::string* out);

}  // namespace dance::server

#endif  // DANCE_SERVER_WEB_PROMETHEUS_H_
