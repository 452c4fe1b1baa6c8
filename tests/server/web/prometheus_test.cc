// The metrics as /metrics renders them (server/web/prometheus.h).
#include <string>

#include "absl/strings/match.h"
#include "gtest/gtest.h"
#include "server/core/metrics.h"
#include "server/web/prometheus.h"

namespace dance::server {
namespace {

TEST(Metrics, HistogramBucketsAreCumulative) {
  Histogram hist({0.001, 0.01, 0.1});
  hist.Observe(0.0005);
  hist.Observe(0.005);
  hist.Observe(0.005);
  hist.Observe(5.0);
  std::string out;
  RenderHistogram(hist, "x", "help", &out);
  EXPECT_TRUE(absl::StrContains(out, "x_bucket{le=\"0.001\"} 1\n"));
  EXPECT_TRUE(absl::StrContains(out, "x_bucket{le=\"0.01\"} 3\n"));
  EXPECT_TRUE(absl::StrContains(out, "x_bucket{le=\"0.1\"} 3\n"));
  EXPECT_TRUE(absl::StrContains(out, "x_bucket{le=\"+Inf\"} 4\n"));
  EXPECT_TRUE(absl::StrContains(out, "x_count 4\n"));
  EXPECT_DOUBLE_EQ(hist.ApproxQuantile(0.5), 0.01);
}

TEST(Metrics, ErrorsAreCountedByKind) {
  ServerMetrics m;
  m.CountError(absl::StatusCode::kResourceExhausted);
  m.CountError(absl::StatusCode::kResourceExhausted);
  const std::string text = RenderPrometheus(m, 3, 10, false);
  EXPECT_TRUE(absl::StrContains(text, "dance_errors_total{kind=\"resource_exhausted\"} 2\n"));
  EXPECT_TRUE(absl::StrContains(text, "dance_sessions_active 3\n"));
}

}  // namespace
}  // namespace dance::server
