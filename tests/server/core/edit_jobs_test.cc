// EditJobs (server/core/edit_jobs.h) over a labelled test double editor: jobs run in order on the workers,
// the queue and the per-client cap refuse with RESOURCE_EXHAUSTED, a job cancelled while queued never runs,
// one cancelled while running stops at its next step and frees its worker, Shutdown ends what is queued.
// Run under TSan too (scripts/test.sh tsan).
#include "server/core/edit_jobs.h"

#include <atomic>
#include <functional>
#include <thread>
#include <memory>
#include <string>
#include <vector>

#include "absl/synchronization/mutex.h"
#include "absl/synchronization/notification.h"
#include "absl/time/clock.h"
#include "gtest/gtest.h"

namespace dance::server {
namespace {

// TEST DOUBLE: an "editor" that takes `steps` steps, each waiting until the test releases it (or, with
// free_running, not at all), and returns `steps` frames. No engine, no model.
class FakeEditor final : public EditorBackend {
 public:
  explicit FakeEditor(int steps, bool free_running) : steps_(steps), free_running_(free_running) {
    desc_.model_id = "fake-editor";
    desc_.window_s = 5.0;
  }
  const EditorDescription& Describe() const override { return desc_; }
  absl::StatusOr<EditOutput> Edit(const EditConfig& config, double /*max_audio_s*/,
                                  const std::function<bool(const EditProgress&)>& progress) const override {
    {
      absl::MutexLock lock(&mu_);
      started_.push_back(config.audio_name);
    }
    for (int i = 1; i <= steps_; ++i) {
      if (!free_running_) {
        absl::MutexLock lock(&mu_);
        auto go = [this]() { return released_ > 0 || stop_; };
        mu_.Await(absl::Condition(&go));
        if (released_ > 0) --released_;
      }
      if (!progress({i, steps_})) return absl::CancelledError("cancelled");
    }
    EditOutput out;
    out.frames.resize(static_cast<size_t>(steps_));
    out.steps = steps_;
    return out;
  }
  void Release(int n) {
    absl::MutexLock lock(&mu_);
    released_ += n;
  }
  void Stop() {
    absl::MutexLock lock(&mu_);
    stop_ = true;
  }
  std::vector<std::string> started() const {
    absl::MutexLock lock(&mu_);
    return started_;
  }
  bool WaitStarted(size_t n) const {
    absl::MutexLock lock(&mu_);
    auto enough = [this, n]() { return started_.size() >= n; };
    return mu_.AwaitWithTimeout(absl::Condition(&enough), absl::Seconds(20));
  }

 private:
  const int steps_;
  const bool free_running_;
  EditorDescription desc_;
  mutable absl::Mutex mu_;
  mutable std::vector<std::string> started_;
  mutable int released_ = 0;
  mutable bool stop_ = false;
};

// Collects one job's events.
struct Events {
  absl::Mutex mu;
  std::vector<EditEvent> all;
  absl::Notification done;
  std::function<void(const EditEvent&)> Listener() {
    return [this](const EditEvent& e) {
      {
        absl::MutexLock lock(&mu);
        all.push_back(e);
      }
      if (e.kind == EditEvent::Kind::kDone) done.Notify();
    };
  }
  EditEvent Last() {
    absl::MutexLock lock(&mu);
    return all.back();
  }
  std::vector<int> Positions() {
    absl::MutexLock lock(&mu);
    std::vector<int> p;
    for (const EditEvent& e : all) {
      if (e.kind == EditEvent::Kind::kQueued) p.push_back(e.position);
    }
    return p;
  }
};

EditConfig Config(const std::string& name) {
  EditConfig c;
  c.audio = "x";
  c.audio_name = name;
  return c;
}

TEST(EditJobs, RunsJobsInOrderWithProgressAndOneResult) {
  FakeEditor editor(3, /*free_running=*/true);
  EditJobs jobs(&editor, {.workers = 1, .max_queued = 4, .max_per_client = 4});
  Events a, b;
  ASSERT_TRUE(jobs.Submit("c", Config("a"), a.Listener()).ok());
  ASSERT_TRUE(jobs.Submit("c", Config("b"), b.Listener()).ok());
  ASSERT_TRUE(a.done.WaitForNotificationWithTimeout(absl::Seconds(20)));
  ASSERT_TRUE(b.done.WaitForNotificationWithTimeout(absl::Seconds(20)));
  EXPECT_EQ(editor.started(), (std::vector<std::string>{"a", "b"}));
  const EditEvent last = b.Last();
  ASSERT_TRUE(last.status.ok()) << last.status;
  ASSERT_NE(last.output, nullptr);
  EXPECT_EQ(last.output->frames.size(), 3u);
  int progress = 0;
  {
    absl::MutexLock lock(&b.mu);
    for (const EditEvent& e : b.all) progress += e.kind == EditEvent::Kind::kProgress;
    EXPECT_EQ(b.all.front().kind, EditEvent::Kind::kQueued);
  }
  EXPECT_EQ(progress, 3);
}

TEST(EditJobs, PerClientCapAndQueueLimitRefuse) {
  FakeEditor editor(1, /*free_running=*/false);
  EditJobs jobs(&editor, {.workers = 1, .max_queued = 1, .max_per_client = 1});
  Events a, b;
  ASSERT_TRUE(jobs.Submit("c1", Config("a"), a.Listener()).ok());
  ASSERT_TRUE(editor.WaitStarted(1));
  Events x;
  absl::StatusOr<std::shared_ptr<EditJob>> again = jobs.Submit("c1", Config("again"), x.Listener());
  EXPECT_EQ(again.status().code(), absl::StatusCode::kResourceExhausted);
  EXPECT_NE(again.status().message().find("already has 1"), std::string::npos) << again.status();
  ASSERT_TRUE(jobs.Submit("c2", Config("b"), b.Listener()).ok());  // waits: the queue's one place
  absl::StatusOr<std::shared_ptr<EditJob>> full = jobs.Submit("c3", Config("c"), x.Listener());
  EXPECT_EQ(full.status().code(), absl::StatusCode::kResourceExhausted);
  EXPECT_NE(full.status().message().find("queue is full"), std::string::npos) << full.status();
  EXPECT_EQ(b.Positions().front(), 0);
  editor.Release(2);
  ASSERT_TRUE(b.done.WaitForNotificationWithTimeout(absl::Seconds(20)));
  EXPECT_TRUE(b.Last().status.ok());
  // c1's job is done: it may submit again.
  Events c;
  EXPECT_TRUE(jobs.Submit("c1", Config("d"), c.Listener()).ok());
  editor.Release(1);
  ASSERT_TRUE(c.done.WaitForNotificationWithTimeout(absl::Seconds(20)));
}

TEST(EditJobs, CancelledWhileQueuedNeverRunsAndWhileRunningFreesTheWorker) {
  FakeEditor editor(1000, /*free_running=*/false);
  EditJobs jobs(&editor, {.workers = 1, .max_queued = 4, .max_per_client = 4});
  Events a, b, c;
  absl::StatusOr<std::shared_ptr<EditJob>> ja = jobs.Submit("c", Config("a"), a.Listener());
  ASSERT_TRUE(ja.ok());
  ASSERT_TRUE(editor.WaitStarted(1));
  absl::StatusOr<std::shared_ptr<EditJob>> jb = jobs.Submit("c", Config("b"), b.Listener());
  ASSERT_TRUE(jb.ok());
  (*jb)->Cancel();
  (*ja)->Cancel();
  editor.Release(1);  // a's next step sees the cancellation
  ASSERT_TRUE(a.done.WaitForNotificationWithTimeout(absl::Seconds(20)));
  EXPECT_EQ(a.Last().status.code(), absl::StatusCode::kCancelled);
  ASSERT_TRUE(b.done.WaitForNotificationWithTimeout(absl::Seconds(20)));
  EXPECT_EQ(b.Last().status.code(), absl::StatusCode::kCancelled);
  EXPECT_EQ(editor.started(), (std::vector<std::string>{"a"}));  // b never ran
  // The worker is free: the next job runs.
  ASSERT_TRUE(jobs.Submit("c", Config("c"), c.Listener()).ok());
  ASSERT_TRUE(editor.WaitStarted(2));
  editor.Stop();
  ASSERT_TRUE(c.done.WaitForNotificationWithTimeout(absl::Seconds(20)));
  EXPECT_EQ(jobs.running(), 0);
}

TEST(EditJobs, ShutdownEndsQueuedJobsUnavailableAndRefusesNewOnes) {
  FakeEditor editor(1, /*free_running=*/false);
  auto jobs = std::make_unique<EditJobs>(&editor, EditJobsOptions{.workers = 1, .max_queued = 4, .max_per_client = 4});
  Events a, b;
  ASSERT_TRUE(jobs->Submit("c", Config("a"), a.Listener()).ok());
  ASSERT_TRUE(editor.WaitStarted(1));
  ASSERT_TRUE(jobs->Submit("c", Config("b"), b.Listener()).ok());
  std::thread stopper([&] { jobs->Shutdown(); });
  ASSERT_TRUE(b.done.WaitForNotificationWithTimeout(absl::Seconds(20)));
  EXPECT_EQ(b.Last().status.code(), absl::StatusCode::kUnavailable);
  editor.Release(1);  // let the running one finish so the worker joins
  stopper.join();
  ASSERT_TRUE(a.done.HasBeenNotified());
  Events x;
  EXPECT_EQ(jobs->Submit("c", Config("late"), x.Listener()).status().code(), absl::StatusCode::kUnavailable);
}

TEST(EditJobs, ValidateEditConfigNamesTheField) {
  EditorDescription d;
  d.window_s = 5.0;
  EditConfig c = Config("a");
  EXPECT_TRUE(ValidateEditConfig(c, d).ok());
  c.steps = 1001;
  EXPECT_NE(ValidateEditConfig(c, d).message().find("steps"), std::string::npos);
  c = Config("a");
  c.overlap_s = 5.0;
  EXPECT_NE(ValidateEditConfig(c, d).message().find("overlap_s"), std::string::npos);
  c = Config("a");
  c.guidance = -0.5f;
  EXPECT_NE(ValidateEditConfig(c, d).message().find("guidance"), std::string::npos);
  c = Config("a");
  c.audio.clear();
  EXPECT_NE(ValidateEditConfig(c, d).message().find("audio"), std::string::npos);
  c = Config("a");
  c.style = {{"waltz", -1.0f}};
  EXPECT_NE(ValidateEditConfig(c, d).message().find("style"), std::string::npos);
}

}  // namespace
}  // namespace dance::server
