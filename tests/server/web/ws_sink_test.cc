// The WebSocket's sink (server/web/ws_sink.h): lossy viewers, lossless performers.
#include <memory>

#include "gtest/gtest.h"
#include "server/core/metrics.h"
#include "server/core/update.h"
#include "server/web/ws_sink.h"

namespace dance::server {
namespace {

UpdatePtr Frame(int64_t index) {
  FrameUpdate f{};
  f.pose.index = index;
  return std::make_shared<const Update>(f);
}

TEST(WsSink, LossyKeepsTheNewestFramesAndCountsDrops) {
  ServerMetrics m;
  WsSink sink(/*lossy=*/true, /*limit=*/2, true, &m);
  for (int i = 0; i < 5; ++i) sink.Deliver(Frame(i));
  sink.Close(absl::OkStatus());
  UpdatePtr u;
  int64_t dropped_before = -1;
  absl::Status final;
  ASSERT_TRUE(sink.Next(&u, &dropped_before, &final));
  EXPECT_EQ(u->frame()->pose.index, 3);
  EXPECT_EQ(dropped_before, 3);
  ASSERT_TRUE(sink.Next(&u, &dropped_before, &final));
  EXPECT_EQ(u->frame()->pose.index, 4);
  EXPECT_EQ(dropped_before, 0);
  EXPECT_FALSE(sink.Next(&u, &dropped_before, &final));
  EXPECT_TRUE(final.ok());
  EXPECT_EQ(m.viewer_frames_dropped_total.load(), 3u);
}

TEST(WsSink, LosslessOverflowFailsWithResourceExhausted) {
  ServerMetrics m;
  WsSink sink(/*lossy=*/false, /*limit=*/3, true, &m);
  for (int i = 0; i < 4; ++i) sink.Deliver(Frame(i));
  UpdatePtr u;
  int64_t dropped_before = 0;
  absl::Status final;
  EXPECT_FALSE(sink.Next(&u, &dropped_before, &final));
  EXPECT_EQ(final.code(), absl::StatusCode::kResourceExhausted);
}

}  // namespace
}  // namespace dance::server
