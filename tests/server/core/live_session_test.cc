// A live session's fan-out (server/core/live_session.h), driven by hand over the test double engine
// (testing/fake_engine.h): every sink gets the same update objects, so a transport encodes each once.
#include <memory>
#include <string>
#include <vector>

#include "absl/synchronization/mutex.h"
#include "absl/time/clock.h"
#include "gtest/gtest.h"
#include "server/core/frame_sink.h"
#include "server/core/live_session.h"
#include "server/core/metrics.h"
#include "tests/server/testing/fake_engine.h"

namespace dance::server {
namespace {

using ::dance::server::testing::FakeBackend;

class RecordingSink : public FrameSink {
 public:
  void Deliver(const UpdatePtr& update) override {
    absl::MutexLock lock(&mu_);
    updates_.push_back(update);
  }
  void Close(const absl::Status& status) override {
    absl::MutexLock lock(&mu_);
    closed_ = true;
    status_ = status;
  }
  size_t Backlog() const override { return 0; }
  std::vector<UpdatePtr> updates() const {
    absl::MutexLock lock(&mu_);
    return updates_;
  }
  bool closed() const {
    absl::MutexLock lock(&mu_);
    return closed_;
  }

 private:
  mutable absl::Mutex mu_;
  std::vector<UpdatePtr> updates_ ABSL_GUARDED_BY(mu_);
  bool closed_ ABSL_GUARDED_BY(mu_) = false;
  absl::Status status_ ABSL_GUARDED_BY(mu_);
};

TEST(LiveSession, EverySinkGetsTheSameUpdateObjects) {
  ServerMetrics metrics;
  FakeBackend backend(absl::ZeroDuration());
  SessionSettings st;
  st.id = "s-1";
  st.client_name = "test";
  st.config.style = {{"none", 1.0f}};
  auto session = std::make_shared<LiveSession>(st, *backend.Open({}), backend.Describe(), &metrics, absl::Now());
  auto performer = std::make_shared<RecordingSink>();
  auto viewer1 = std::make_shared<RecordingSink>();
  auto viewer2 = std::make_shared<RecordingSink>();
  session->AttachPerformer(performer);
  ASSERT_TRUE(session->AddViewer(viewer1).ok());
  ASSERT_TRUE(session->AddViewer(viewer2).ok());

  bool pause = false;
  ASSERT_TRUE(session->EnqueueAudio(0, std::string(2 * 3200 * sizeof(float), '\0'), absl::Now(), &pause).ok());
  ASSERT_TRUE(session->EnqueueEnd(absl::Now()).ok());
  ASSERT_TRUE(session->Drain(absl::Now()).ok());
  while (session->StepsReady() > 0) {
    EngineStream* stream = session->engine_stream();
    ASSERT_TRUE(backend.StepBatch({&stream, 1}).ok());
    session->AfterStep(absl::Now());
  }
  ASSERT_TRUE(session->ReadyToComplete());
  EXPECT_TRUE(session->Complete(absl::OkStatus()).ok());
  const SessionSummary summary = session->Summary();
  session->CloseSinks();

  const std::vector<UpdatePtr> got = performer->updates();
  ASSERT_EQ(got.size(), 1u + 8u + 1u);  // info, two steps of 4 frames, end
  EXPECT_EQ(got.front(), session->info());
  ASSERT_NE(got.front()->info(), nullptr);
  EXPECT_EQ(got.front()->info()->session_id, "s-1");
  for (size_t i = 1; i <= 8; ++i) {
    ASSERT_TRUE(got[i]->is_frame());
    EXPECT_EQ(got[i]->frame()->pose.index, static_cast<int64_t>(i - 1));
  }
  ASSERT_NE(got.back()->end(), nullptr);
  EXPECT_EQ(got.back()->end()->frames, 8);
  EXPECT_EQ(got.back()->end()->reason, "end_of_audio");
  // Not copies: the very same objects, so their memoised wire forms are shared too.
  EXPECT_EQ(viewer1->updates(), got);
  EXPECT_EQ(viewer2->updates(), got);
  EXPECT_TRUE(performer->closed());
  EXPECT_TRUE(viewer1->closed());

  EXPECT_EQ(summary.session_id, "s-1");
  EXPECT_EQ(summary.client_name, "test");
  EXPECT_EQ(summary.frames, 8);
  EXPECT_DOUBLE_EQ(summary.audio_ms, 1000.0 * 6400 / 24000);
  EXPECT_EQ(summary.viewers, 2);
  ASSERT_EQ(summary.style.size(), 1u);
  EXPECT_EQ(summary.style[0].first, "none");
}

}  // namespace
}  // namespace dance::server
