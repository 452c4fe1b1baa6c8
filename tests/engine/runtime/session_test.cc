// Session behaviour on a C++-built tiny model: chunking invariance, batching, snapshot/restore, settings.
#include "engine/runtime/session.h"

#include <random>
#include <set>

#include "absl/strings/match.h"
#include "gtest/gtest.h"
#include "tests/engine/runtime/testing/tiny_model.h"

namespace dance::engine {
namespace {

using testing::LoadTinyModel;
using testing::TestAudio;

std::unique_ptr<Session> MakeSession(std::shared_ptr<const Model> model, SessionOptions opt = {}) {
  absl::StatusOr<std::unique_ptr<Session>> s = Session::Create(std::move(model), opt);
  EXPECT_TRUE(s.ok()) << s.status();
  return s.ok() ? *std::move(s) : nullptr;
}

SessionOptions Opts(uint64_t seed, SamplingOptions sampling = {}) {
  SessionOptions o;
  o.seed = seed;
  o.sampling = sampling;
  return o;
}

SamplingOptions Sampling(float temperature, int top_k = 0, float guidance = 1.0f) {
  SamplingOptions s;
  s.temperature = temperature;
  s.top_k = top_k;
  s.guidance = guidance;
  return s;
}

void DrainSteps(Session& s) {
  while (s.StepsReady() > 0) ASSERT_TRUE(s.Step().ok());
}

// Pushes `audio` in the given chunk sizes (cycled), stepping whenever possible, then ends the stream.
std::vector<PoseFrame> RunStream(Session& s, const std::vector<float>& audio, const std::vector<size_t>& chunks) {
  size_t pos = 0, i = 0;
  while (pos < audio.size()) {
    const size_t n = std::min(chunks[i++ % chunks.size()], audio.size() - pos);
    EXPECT_TRUE(s.PushAudio(absl::MakeConstSpan(audio.data() + pos, n)).ok());
    pos += n;
    DrainSteps(s);
  }
  s.EndOfAudio();
  DrainSteps(s);
  std::vector<PoseFrame> out;
  s.PopFrames(&out);
  return out;
}

void ExpectSameFrames(const std::vector<PoseFrame>& a, const std::vector<PoseFrame>& b, float tol = 0.0f) {
  ASSERT_EQ(a.size(), b.size());
  for (size_t i = 0; i < a.size(); ++i) {
    ASSERT_EQ(a[i].index, b[i].index);
    ASSERT_EQ(a[i].upper_code, b[i].upper_code) << "frame " << i;
    ASSERT_EQ(a[i].lower_code, b[i].lower_code) << "frame " << i;
    for (int j = 0; j < 24; ++j) {
      ASSERT_LE((a[i].positions[j] - b[i].positions[j]).norm(), tol) << "frame " << i << " joint " << j;
      ASSERT_LE(a[i].rotations[j].angularDistance(b[i].rotations[j]), tol + 1e-3f) << "frame " << i;
    }
  }
}

TEST(Session, EmitsWholePeriodsFromFrameFour) {
  auto model = LoadTinyModel();
  auto s = MakeSession(model);
  std::vector<PoseFrame> frames = RunStream(*s, TestAudio(2.0), {4000});
  // 2 s = 15 periods of audio = 15 steps (s = 0); step t emits period t + 1, so periods 1..15 (the last
  // one anticipates beyond the audio) and period 0 has no pose.
  ASSERT_EQ(frames.size(), 15u * 4);
  for (size_t i = 0; i < frames.size(); ++i) {
    EXPECT_EQ(frames[i].index, static_cast<int64_t>(i) + 4);
    EXPECT_DOUBLE_EQ(frames[i].time_s, frames[i].index / 30.0);
    for (int j = 1; j < 24; ++j) {
      const float len = (frames[i].positions[j] - frames[i].positions[model->skeleton().parents[j]]).norm();
      EXPECT_NEAR(len, model->skeleton().bone_lengths[j], 1e-4f);
    }
  }
}

TEST(Session, CodesVaryWithSampling) {
  auto model = LoadTinyModel();
  auto s = MakeSession(model, Opts(5));
  std::vector<PoseFrame> frames = RunStream(*s, TestAudio(3.0), {24000});
  std::set<int> codes;
  for (const PoseFrame& f : frames) codes.insert(f.upper_code);
  EXPECT_GT(codes.size(), 3u);
}

TEST(Session, ChunkingInvariance) {
  auto model = LoadTinyModel();
  const std::vector<float> audio = TestAudio(3.3);
  SessionOptions opt = Opts(11);
  auto a = MakeSession(model, opt);
  const std::vector<PoseFrame> reference = RunStream(*a, audio, {static_cast<size_t>(audio.size())});
  std::mt19937 gen(3);
  for (int trial = 0; trial < 4; ++trial) {
    std::vector<size_t> chunks;
    for (int i = 0; i < 50; ++i) chunks.push_back(1 + gen() % (trial == 0 ? 7 : 5000));
    auto b = MakeSession(model, opt);
    ExpectSameFrames(reference, RunStream(*b, audio, chunks));
  }
}

TEST(Session, ChunkingInvarianceAt44100Stereo) {
  auto model = LoadTinyModel();
  std::vector<float> mono = TestAudio(2.0, 44100), stereo;
  for (float v : mono) {
    stereo.push_back(v);
    stereo.push_back(0.5f * v);
  }
  SessionOptions opt = Opts(2);
  opt.input_sample_rate = 44100;
  opt.input_channels = 2;
  auto a = MakeSession(model, opt);
  auto b = MakeSession(model, opt);
  ExpectSameFrames(RunStream(*a, stereo, {stereo.size()}), RunStream(*b, stereo, {2, 882, 46, 10000}));
}

TEST(Session, SnapshotRestoreContinuesExactly) {
  auto model = LoadTinyModel();
  const std::vector<float> audio = TestAudio(4.0);
  const size_t half = audio.size() / 2 + 123;
  auto s = MakeSession(model, Opts(9, Sampling(0.9f, 8)));
  ASSERT_TRUE(s->PushAudio(absl::MakeConstSpan(audio.data(), half)).ok());
  DrainSteps(*s);
  absl::StatusOr<SessionSnapshot> snap = s->Snapshot();
  ASSERT_TRUE(snap.ok());
  std::vector<float> rest(audio.begin() + half, audio.end());
  std::vector<PoseFrame> first = RunStream(*s, rest, {1000});
  // Restore into the same session and into a fresh one: both continue identically.
  ASSERT_TRUE(s->Restore(*snap).ok());
  std::vector<PoseFrame> second = RunStream(*s, rest, {777});
  auto fresh = MakeSession(model, Opts(9, Sampling(0.9f, 8)));
  ASSERT_TRUE(fresh->Restore(*snap).ok());
  std::vector<PoseFrame> third = RunStream(*fresh, rest, {5000});
  ExpectSameFrames(first, second);
  ExpectSameFrames(first, third);
}

TEST(Session, ResetReproducesAFreshSession) {
  auto model = LoadTinyModel();
  const std::vector<float> audio = TestAudio(2.0);
  auto s = MakeSession(model, Opts(4));
  const std::vector<PoseFrame> a = RunStream(*s, audio, {3000});
  s->Reset();
  ExpectSameFrames(a, RunStream(*s, audio, {5000}));
}

TEST(Session, StepBatchMatchesSteppingAlone) {
  auto model = LoadTinyModel();
  const std::vector<float> audio = TestAudio(2.5);
  std::vector<std::vector<PoseFrame>> alone;
  std::vector<std::unique_ptr<Session>> batch;
  for (int i = 0; i < 5; ++i) {
    SessionOptions opt = Opts(i);
    if (i == 1) opt.style = {{"waltz", 1.0f}};
    if (i == 2) opt.sampling.guidance = 2.0f;
    if (i == 3) opt.sampling.temperature = 0.0f;
    auto a = MakeSession(model, opt);
    alone.push_back(RunStream(*a, audio, {audio.size()}));
    batch.push_back(MakeSession(model, opt));
    ASSERT_TRUE(batch.back()->PushAudio(audio).ok());
    batch.back()->EndOfAudio();
  }
  std::vector<Session*> ptrs;
  for (auto& s : batch) ptrs.push_back(s.get());
  while (ptrs[0]->StepsReady() > 0) ASSERT_TRUE(StepBatch(ptrs).ok());
  for (int i = 0; i < 5; ++i) {
    std::vector<PoseFrame> got;
    batch[i]->PopFrames(&got);
    ExpectSameFrames(alone[i], got, 1e-4f);
  }
}

TEST(Session, StepBatchHandlesSessionsOfDifferentModels) {
  auto model_a = LoadTinyModel();
  testing::TinyModelOptions other;
  other.seed = 2;
  other.d_model = 8;
  other.vq_width = 4;
  auto model_b = LoadTinyModel(other);
  const std::vector<float> audio = TestAudio(2.0);
  std::vector<std::vector<PoseFrame>> alone;
  std::vector<std::unique_ptr<Session>> batch;
  for (int i = 0; i < 4; ++i) {
    auto model = i % 2 == 0 ? model_a : model_b;
    auto a = MakeSession(model, Opts(i));
    alone.push_back(RunStream(*a, audio, {audio.size()}));
    batch.push_back(MakeSession(model, Opts(i)));
    ASSERT_TRUE(batch.back()->PushAudio(audio).ok());
    batch.back()->EndOfAudio();
  }
  std::vector<Session*> ptrs;
  for (auto& s : batch) ptrs.push_back(s.get());
  while (ptrs[0]->StepsReady() > 0) ASSERT_TRUE(StepBatch(ptrs).ok());
  for (int i = 0; i < 4; ++i) {
    std::vector<PoseFrame> got;
    batch[i]->PopFrames(&got);
    ExpectSameFrames(alone[i], got, 1e-4f);
  }
}

TEST(Session, GuidanceSnapshotAndToggleMidStream) {
  auto model = LoadTinyModel();
  const std::vector<float> audio = TestAudio(3.0);
  const size_t third = audio.size() / 3;
  auto s = MakeSession(model, Opts(6));
  ASSERT_TRUE(s->PushAudio(absl::MakeConstSpan(audio.data(), third)).ok());
  DrainSteps(*s);
  ASSERT_TRUE(s->SetSampling(Sampling(1.0f, 0, 3.0f)).ok());  // guidance on mid-stream
  ASSERT_TRUE(s->PushAudio(absl::MakeConstSpan(audio.data() + third, third)).ok());
  DrainSteps(*s);
  absl::StatusOr<SessionSnapshot> snap = s->Snapshot();
  ASSERT_TRUE(snap.ok());
  std::vector<float> rest(audio.begin() + 2 * third, audio.end());
  std::vector<PoseFrame> first = RunStream(*s, rest, {999});
  ASSERT_TRUE(s->Restore(*snap).ok());
  ExpectSameFrames(first, RunStream(*s, rest, {4321}));
  EXPECT_GT(s->StateBytes(), 0);
}

TEST(Session, StepBatchRefusesDuplicatesAndUnreadySessions) {
  auto model = LoadTinyModel();
  auto a = MakeSession(model);
  auto b = MakeSession(model);
  ASSERT_TRUE(a->PushAudio(TestAudio(1.0)).ok());
  std::vector<Session*> dup = {a.get(), a.get()};
  EXPECT_EQ(StepBatch(dup).code(), absl::StatusCode::kInvalidArgument);
  std::vector<Session*> unready = {a.get(), b.get()};
  EXPECT_EQ(StepBatch(unready).code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_EQ(a->steps_done(), 0);
  EXPECT_EQ(b->Step().code(), absl::StatusCode::kFailedPrecondition);
}

TEST(Session, BadSettingsGiveClearErrors) {
  auto model = LoadTinyModel();
  SessionOptions polka;
  polka.style = {{"polka", 1.0f}};
  absl::Status s = Session::Create(model, polka).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kNotFound);
  EXPECT_TRUE(absl::StrContains(s.message(), "polka")) << s;
  EXPECT_TRUE(absl::StrContains(s.message(), "waltz")) << s;
  s = Session::Create(model, Opts(0, Sampling(-1.0f))).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_TRUE(absl::StrContains(s.message(), "temperature")) << s;
  SessionOptions bad;
  bad.input_sample_rate = 1000;
  EXPECT_FALSE(Session::Create(model, bad).ok());
  bad = SessionOptions();
  bad.input_channels = 0;
  EXPECT_FALSE(Session::Create(model, bad).ok());
  bad = SessionOptions();
  bad.style = {{"waltz", -1.0f}};
  EXPECT_FALSE(Session::Create(model, bad).ok());
  EXPECT_FALSE(Session::Create(nullptr, {}).ok());
  SessionOptions stereo;
  stereo.input_channels = 2;
  auto ok = MakeSession(model, stereo);
  const float odd[3] = {0, 0, 0};
  EXPECT_FALSE(ok->PushAudio(odd).ok());
  EXPECT_FALSE(ok->SetStyle({{"rumba", 1.0f}}).ok());
  SamplingOptions bad_p;
  bad_p.top_p = 0.0f;
  EXPECT_FALSE(ok->SetSampling(bad_p).ok());
  ok->EndOfAudio();
  EXPECT_EQ(ok->PushAudio(absl::Span<const float>()).code(), absl::StatusCode::kFailedPrecondition);
}

TEST(Session, StyleChangeMidStreamChangesTheContinuationOnly) {
  auto model = LoadTinyModel();
  const std::vector<float> audio = TestAudio(3.0);
  auto a = MakeSession(model, Opts(1, Sampling(0.0f)));
  auto b = MakeSession(model, Opts(1, Sampling(0.0f)));
  const size_t half = audio.size() / 2;
  for (Session* s : {a.get(), b.get()}) {
    ASSERT_TRUE(s->PushAudio(absl::MakeConstSpan(audio.data(), half)).ok());
    DrainSteps(*s);
  }
  ASSERT_TRUE(b->SetStyle({{"waltz", 0.3f}, {"tango", 0.7f}}).ok());
  std::vector<float> rest(audio.begin() + half, audio.end());
  std::vector<PoseFrame> fa, fb;
  a->PopFrames(&fa);
  b->PopFrames(&fb);
  ExpectSameFrames(fa, fb);
  fa = RunStream(*a, rest, {4000});
  fb = RunStream(*b, rest, {4000});
  ASSERT_EQ(fa.size(), fb.size());
  bool differs = false;
  for (size_t i = 0; i < fa.size(); ++i) differs |= fa[i].upper_code != fb[i].upper_code;
  EXPECT_TRUE(differs);
}

TEST(Session, Int16MatchesFloat) {
  auto model = LoadTinyModel();
  std::vector<float> audio = TestAudio(1.5);
  std::vector<int16_t> pcm;
  for (float& v : audio) {
    pcm.push_back(static_cast<int16_t>(std::lround(v * 16384.0f)));
    v = pcm.back() / 32768.0f;
  }
  auto a = MakeSession(model, Opts(3));
  auto b = MakeSession(model, Opts(3));
  ASSERT_TRUE(b->PushAudioInt16(pcm).ok());
  b->EndOfAudio();
  DrainSteps(*b);
  std::vector<PoseFrame> fb;
  b->PopFrames(&fb);
  ExpectSameFrames(RunStream(*a, audio, {audio.size()}), fb);
}

}  // namespace
}  // namespace dance::engine
