// The scheduler over a labelled test double engine (testing/fake_engine.h): no model, fixed step cost.
#include <map>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/match.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/clock.h"
#include "gtest/gtest.h"
#include "server/core/live_session.h"
#include "server/core/metrics.h"
#include "server/core/scheduler.h"
#include "tests/server/testing/fake_engine.h"

namespace dance::server {
namespace {

using ::dance::server::testing::FakeBackend;

class Completions {
 public:
  void Record(const std::string& id, const absl::Status& st) {
    absl::MutexLock lock(&mu_);
    done_[id] = st;
    order_.push_back(id);
  }
  // Waits (generously) until `id` completed; its status, or DEADLINE_EXCEEDED("test: ...") if it never did.
  absl::Status Wait(const std::string& id, absl::Duration timeout = absl::Seconds(60)) {
    absl::MutexLock lock(&mu_);
    auto has = [&]() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_) { return done_.count(id) > 0; };
    if (!mu_.AwaitWithTimeout(absl::Condition(&has), timeout)) return absl::DeadlineExceededError("test: not done");
    return done_[id];
  }
  std::vector<std::string> order() {
    absl::MutexLock lock(&mu_);
    return order_;
  }

 private:
  absl::Mutex mu_;
  std::map<std::string, absl::Status> done_ ABSL_GUARDED_BY(mu_);
  std::vector<std::string> order_ ABSL_GUARDED_BY(mu_);
};

std::shared_ptr<LiveSession> NewSession(const FakeBackend& backend, Scheduler* sched, ServerMetrics* metrics,
                                        const std::string& id, absl::Duration idle_timeout) {
  SessionSettings st;
  st.id = id;
  st.idle_timeout = idle_timeout;
  st.wake = [sched] { sched->Wake(); };
  return std::make_shared<LiveSession>(st, *backend.Open({}), backend.Describe(), metrics, absl::Now());
}

absl::Status Feed(LiveSession& s, int64_t offset, int64_t samples) {
  bool pause = false;
  return s.EnqueueAudio(offset, std::string(static_cast<size_t>(samples) * sizeof(float), '\0'), absl::Now(),
                        &pause);
}

// Issue 5: under overload a session whose client kept sending ended with an idle timeout: the scheduler
// was busy stepping others (a pass lasted as long as any step was ready), the new session sat in its
// incoming list undrained, and idle time was measured against the last *drained* chunk. Now the idle
// time runs from the last chunk's arrival, and every pass is one step round, so new sessions and
// timeouts are handled while the engine is behind.
TEST(Scheduler, IdleTimeoutCountsArrivalsNotDrainsAndBusyPassesStayShort) {
  ServerMetrics metrics;
  FakeBackend backend(absl::Milliseconds(50));
  Completions done;
  Scheduler sched(&backend, &metrics, {}, [&](LiveSession& s, const absl::Status& st) { done.Record(s.id(), st); });
  sched.Start();
  // The hog: 60 steps queued at once, >= 3 s of scheduler time.
  auto hog = NewSession(backend, &sched, &metrics, "hog", absl::Seconds(30));
  ASSERT_TRUE(Feed(*hog, 0, 60 * 3200).ok());
  ASSERT_TRUE(hog->EnqueueEnd(absl::Now()).ok());
  sched.Add(hog);
  for (int i = 0; i < 6000 && metrics.steps_total.load() == 0; ++i) absl::SleepFor(absl::Milliseconds(1));
  ASSERT_GT(metrics.steps_total.load(), 0u);
  // A real-time client joining while the hog runs (20 ms chunks for 2.5 s, idle timeout 1.5 s), and one
  // that never sends anything (idle timeout 300 ms).
  auto live = NewSession(backend, &sched, &metrics, "live", absl::Milliseconds(1500));
  auto silent = NewSession(backend, &sched, &metrics, "silent", absl::Milliseconds(300));
  sched.Add(live);
  sched.Add(silent);
  std::thread feeder([&] {
    const absl::Time t0 = absl::Now();
    int64_t off = 0;
    while (absl::Now() - t0 < absl::Milliseconds(2500)) {
      if (!Feed(*live, off, 480).ok()) return;
      off += 480;
      absl::SleepFor(absl::Milliseconds(20));
    }
    (void)live->EnqueueEnd(absl::Now());
  });
  const absl::Status silent_st = done.Wait("silent");
  const absl::Status live_st = done.Wait("live");
  const absl::Status hog_st = done.Wait("hog");
  feeder.join();
  EXPECT_EQ(silent_st.code(), absl::StatusCode::kDeadlineExceeded) << silent_st;
  EXPECT_TRUE(absl::StrContains(silent_st.message(), "idle timeout")) << silent_st;
  EXPECT_TRUE(live_st.ok()) << live_st;
  EXPECT_TRUE(hog_st.ok()) << hog_st;
  // The silent one timed out while the hog was still being stepped (timeouts are not starved).
  const std::vector<std::string> order = done.order();
  ASSERT_EQ(order.size(), 3u);
  EXPECT_EQ(order.front(), "silent");
  sched.Stop();
}

}  // namespace
}  // namespace dance::server
