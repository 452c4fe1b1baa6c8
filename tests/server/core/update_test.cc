// The core's update type (server/core/update.h): wire forms memoised per update.
#include <atomic>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "absl/time/clock.h"
#include "gtest/gtest.h"
#include "server/core/update.h"

namespace dance::server {
namespace {

TEST(Update, EachWireFormIsBuiltOnceHoweverManyThreadsAsk) {
  static const int slot = ReserveEncodingSlot();
  const auto update = std::make_shared<const Update>(EndUpdate{4, 133.0, "end_of_audio"});
  std::atomic<int> builds{0};
  std::vector<const std::string*> seen(8, nullptr);
  std::vector<std::thread> threads;
  for (size_t t = 0; t < seen.size(); ++t) {
    threads.emplace_back([&, t] {
      seen[t] = &update->Encoding<std::string>(slot, [&] {
        builds.fetch_add(1);
        absl::SleepFor(absl::Milliseconds(5));  // let the others arrive while it builds
        return std::string("end ") + std::to_string(update->end()->frames);
      });
    });
  }
  for (std::thread& t : threads) t.join();
  EXPECT_EQ(builds.load(), 1);
  for (const std::string* s : seen) {
    ASSERT_EQ(s, seen[0]);
    EXPECT_EQ(*s, "end 4");
  }
}

TEST(Update, KindAccessors) {
  const Update frame(FrameUpdate{});
  EXPECT_TRUE(frame.is_frame());
  EXPECT_NE(frame.frame(), nullptr);
  EXPECT_EQ(frame.info(), nullptr);
  const Update event(EventUpdate{EventKind::kWarning, 1.0, 2, "w"});
  EXPECT_FALSE(event.is_frame());
  ASSERT_NE(event.event(), nullptr);
  EXPECT_EQ(event.event()->message, "w");
}

}  // namespace
}  // namespace dance::server
