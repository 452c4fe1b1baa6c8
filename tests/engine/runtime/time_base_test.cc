// TimeBase's playback of warped poses on the real timeline (docs/model.md section 1): real frame m shows
// the warped pose at w = max(W_m, 5), linearly interpolated. Warped pose j is a rigid pose moved to x = j, so
// each real frame's pelvis x reads back the w it was shown at.
#include "engine/runtime/internal/time_base.h"

#include <algorithm>
#include <cmath>
#include <deque>
#include <memory>
#include <vector>

#include "gtest/gtest.h"
#include "engine/runtime/model.h"
#include "engine/runtime/style_mix.h"
#include "engine/vq/pose_reconstructor.h"
#include "tests/engine/runtime/testing/tiny_model.h"

namespace dance::engine {
namespace {

// W_m of every real frame and the emitted frames' pelvis x, for clicks at `bpm` danced as `style`.
void PlayBack(const Model& model, const char* style, double bpm, int64_t* first, std::deque<double>* starts,
              std::vector<PoseFrame>* frames) {
  absl::StatusOr<TimeBase> t = TimeBase::Create(model, 24000, 1);
  ASSERT_TRUE(t.ok()) << t.status();
  absl::StatusOr<ResolvedStyle> s = ResolveStyle(model, {{style, 1.0f}});
  ASSERT_TRUE(s.ok()) << s.status();
  t->SetStyle(*s);
  // With no pose decoded yet nothing is emitted, so every real frame's start stays queued.
  ASSERT_TRUE(t->PushFloat(testing::ClickAudio(20.0, bpm), frames).ok());
  ASSERT_TRUE(frames->empty());
  *first = t->state().warp.next_output;  // starts[i] is W of real frame first + i
  *starts = t->state().warp.starts;
  // A rigid pose with canonical bones: the rest pose, bone-projected.
  std::array<Eigen::Vector3f, 24> rest;
  const Skeleton& sk = model.skeleton();
  for (int j = 0; j < 24; ++j) rest[j] = (j == 0 ? Eigen::Vector3f::Zero() : rest[sk.parents[j]]) + sk.offsets[j];
  PoseReconstructor(sk).ProjectBoneLengths(rest);
  const int64_t warped = t->state().warp.clock.warped_frames();
  for (int64_t j = model.config().frames_per_step; j < warped; ++j) {
    std::array<Eigen::Vector3f, 24>& p = t->AddWarpedPose({0, 0});
    for (int k = 0; k < 24; ++k) p[k] = rest[k] + Eigen::Vector3f(static_cast<float>(j), 0.0f, 0.0f);
  }
  t->EmitWarped(frames);
  for (PoseFrame& f : *frames) f.positions[0].x() -= rest[0].x();
}

TEST(TimeBase, RealFramesShowTheWarpedPoseAtTheirStart) {
  absl::StatusOr<std::shared_ptr<const Model>> model = LoadModel("models/default.dncw");
  ASSERT_TRUE(model.ok()) << model.status() << " (run from the source root)";
  // Clicks at 100 BPM danced as a cha-cha (reference 125 BPM): the clock runs at about 0.8 warped frames
  // per real frame, so some real frames share an interval (a, a + 1]; at 150 BPM it runs faster than 1.
  for (double bpm : {100.0, 150.0}) {
    int64_t first = 0;
    std::deque<double> starts;
    std::vector<PoseFrame> frames;
    PlayBack(**model, "cha-cha", bpm, &first, &starts, &frames);
    ASSERT_GT(frames.size(), 500u) << bpm;
    int shared = 0;
    for (size_t i = 0; i < frames.size(); ++i) {
      const int64_t m = frames[i].index - first;
      ASSERT_GE(m, 0);
      ASSERT_LT(static_cast<size_t>(m), starts.size());
      const double want = std::max(starts[m], 5.0);
      EXPECT_NEAR(frames[i].positions[0].x(), want, 2e-3) << "bpm " << bpm << " frame " << m;
      if (m > 0 && std::ceil(std::max(starts[m - 1], 5.0)) == std::ceil(want)) ++shared;
    }
    if (bpm == 100.0) {
      EXPECT_GT(shared, 100) << "the slow clock puts real frames in one interval";
    }
  }
}

}  // namespace
}  // namespace dance::engine
