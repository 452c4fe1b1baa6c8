// Session behaviour on a C++-built tiny model: chunking invariance, batching, snapshot/restore, settings.
#include "engine/runtime/session.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <optional>
#include <random>
#include <set>
#include <tuple>

#include "absl/strings/match.h"
#include "gtest/gtest.h"
#include "tests/engine/runtime/testing/session_run.h"
#include "tests/engine/runtime/testing/tiny_model.h"

namespace dance::engine {
namespace {

using testing::DrainSteps;
using testing::LoadTinyModel;
using testing::RunStream;
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

// Steps taken over the second half of `audio` (after the beat tracker has settled on the first half).
double StepsInSecondHalf(Session& s, const std::vector<float>& audio) {
  const size_t half = audio.size() / 2;
  EXPECT_TRUE(s.PushAudio(absl::MakeConstSpan(audio.data(), half)).ok());
  DrainSteps(s);
  const int64_t at_half = s.steps_done();
  EXPECT_TRUE(s.PushAudio(absl::MakeConstSpan(audio.data() + half, audio.size() - half)).ok());
  DrainSteps(s);
  return static_cast<double>(s.steps_done() - at_half);
}

// Frames (of the first min(size) of each) whose upper (stream 0) or lower (1) codes differ.
int CodesDiffer(const std::vector<PoseFrame>& a, const std::vector<PoseFrame>& b, int stream) {
  int n = 0;
  for (size_t i = 0; i < std::min(a.size(), b.size()); ++i) {
    n += stream == 0 ? a[i].upper_code != b[i].upper_code : a[i].lower_code != b[i].lower_code;
  }
  return n;
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

// Runs `audio` in chunks of `chunk`, popping the beats after every push; returns them all.
std::vector<double> BeatsOfStream(Session& s, const std::vector<float>& audio, size_t chunk) {
  std::vector<double> beats;
  for (size_t pos = 0; pos < audio.size(); pos += chunk) {
    const size_t n = std::min(chunk, audio.size() - pos);
    EXPECT_TRUE(s.PushAudio(absl::MakeConstSpan(audio.data() + pos, n)).ok());
    DrainSteps(s);
    s.PopBeats(&beats);
  }
  s.EndOfAudio();
  DrainSteps(s);
  s.PopBeats(&beats);
  return beats;
}

TEST(Session, PopBeatsGivesTheTrackersBeatsOnTheClicks) {
  auto model = LoadTinyModel();
  const std::vector<float> audio = testing::ClickAudio(12.0, 120.0);  // clicks at k x 0.5 s
  auto a = MakeSession(model, Opts(1));
  const std::vector<double> beats = BeatsOfStream(*a, audio, 1000);
  ASSERT_GE(beats.size(), 14u);
  int on_click = 0, late = 0;
  for (size_t i = 0; i < beats.size(); ++i) {
    if (i > 0) ASSERT_GT(beats[i], beats[i - 1]);
    if (beats[i] < 4.0) continue;  // the tracker settles first
    ++late;
    const double k = std::round(beats[i] / 0.5);
    on_click += std::abs(beats[i] - 0.5 * k) < 0.04;
  }
  EXPECT_GE(late, 14);  // 8 s of clicks at 2 a second
  EXPECT_GE(on_click, late - 1) << "beats after 4 s off the clicks: " << late - on_click << " of " << late;
  // No beat twice, nothing popped twice, and the same beats however the audio is chunked.
  auto b = MakeSession(model, Opts(1));
  EXPECT_EQ(BeatsOfStream(*b, audio, 4321), beats);
  std::vector<double> none;
  b->PopBeats(&none);
  EXPECT_TRUE(none.empty());
}

TEST(Session, UnpoppedBeatsTravelInSnapshotsAndResetForgetsThem) {
  auto model = LoadTinyModel();
  const std::vector<float> audio = testing::ClickAudio(8.0, 120.0);
  auto s = MakeSession(model, Opts(2));
  ASSERT_TRUE(s->PushAudio(absl::MakeConstSpan(audio.data(), audio.size() / 2)).ok());
  DrainSteps(*s);
  absl::StatusOr<SessionSnapshot> snap = s->Snapshot();
  ASSERT_TRUE(snap.ok());
  std::vector<double> original, restored;
  s->PopBeats(&original);
  ASSERT_FALSE(original.empty());
  auto fresh = MakeSession(model, Opts(2));
  ASSERT_TRUE(fresh->Restore(*snap).ok());
  fresh->PopBeats(&restored);
  EXPECT_EQ(restored, original);
  ASSERT_TRUE(fresh->Restore(*snap).ok());
  fresh->Reset();
  std::vector<double> after_reset;
  fresh->PopBeats(&after_reset);
  EXPECT_TRUE(after_reset.empty());
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
  for (int i = 0; i < 7; ++i) {
    SessionOptions opt = Opts(i);
    if (i == 1 || i == 5) opt.style = {{"waltz", 1.0f}};
    if (i == 2 || i == 5) opt.sampling.guidance = 2.0f;
    if (i == 3) opt.sampling.temperature = 0.0f;
    if (i == 5 || i == 6) opt.sampling.music_guidance = 0.5f;  // four lanes; two
    auto a = MakeSession(model, opt);
    alone.push_back(RunStream(*a, audio, {audio.size()}));
    batch.push_back(MakeSession(model, opt));
    ASSERT_TRUE(batch.back()->PushAudio(audio).ok());
    batch.back()->EndOfAudio();
  }
  std::vector<Session*> ptrs;
  for (auto& s : batch) ptrs.push_back(s.get());
  while (ptrs[0]->StepsReady() > 0) ASSERT_TRUE(StepBatch(ptrs).ok());
  for (int i = 0; i < 7; ++i) {
    std::vector<PoseFrame> got;
    batch[i]->PopFrames(&got);
    ExpectSameFrames(alone[i], got, 1e-4f);
  }
}

TEST(Session, GuidanceAndTopPDefaultToTheModels) {
  // Negative SamplingOptions::guidance = the model's metadata "sampling": {"guidance": W} (1 without it).
  testing::TinyModelOptions o;
  auto plain = LoadTinyModel(o);
  o.guidance = 2.5;
  auto guided = LoadTinyModel(o);
  EXPECT_EQ(plain->default_guidance(), 1.0f);
  EXPECT_EQ(guided->default_guidance(), 2.5f);
  const std::vector<float> audio = TestAudio(2.5);
  auto run = [&](std::shared_ptr<const Model> m, float w) {
    SessionOptions opt = Opts(3);
    opt.style = {{"waltz", 1.0f}};
    opt.sampling.guidance = w;
    auto s = MakeSession(std::move(m), opt);
    return std::make_pair(s->guidance(), RunStream(*s, audio, {audio.size()}));
  };
  const auto [w_default, by_default] = run(guided, kModelDefaultGuidance);
  EXPECT_EQ(w_default, 2.5f);
  ExpectSameFrames(by_default, run(plain, 2.5f).second);
  const auto [w_off, off] = run(guided, 1.0f);  // explicit 1 turns it off
  EXPECT_EQ(w_off, 1.0f);
  ExpectSameFrames(off, run(plain, kModelDefaultGuidance).second);
  EXPECT_GT(CodesDiffer(off, by_default, 0), 0);
  // The nucleus cut likewise: metadata "sampling": {"top_p": P}, negative = the model's.
  o.guidance = -1.0;
  o.top_p = 0.5;
  auto cut = LoadTinyModel(o);
  EXPECT_EQ(plain->default_top_p(), 1.0f);
  EXPECT_EQ(cut->default_top_p(), 0.5f);
  auto run_p = [&](std::shared_ptr<const Model> m, float p) {
    SessionOptions opt = Opts(4);
    opt.sampling.top_p = p;
    auto s = MakeSession(std::move(m), opt);
    return std::make_pair(s->top_p(), RunStream(*s, audio, {audio.size()}));
  };
  const auto [p_default, cut_default] = run_p(cut, kModelDefaultTopP);
  EXPECT_EQ(p_default, 0.5f);
  ExpectSameFrames(cut_default, run_p(plain, 0.5f).second);
  ExpectSameFrames(run_p(cut, 1.0f).second, run_p(plain, kModelDefaultTopP).second);
  // Bad metadata is refused with the key named.
  for (const auto& [key, value] : std::vector<std::pair<std::string, double>>{{"guidance", 101.0}, {"top_p", 0.0}}) {
    WeightsWriter w = testing::TinyModelWriter(o);
    w.metadata()["sampling"][key] = value;
    const std::string path = ::testing::TempDir() + "/bad_sampling.dncw";
    ASSERT_TRUE(w.WriteFile(path).ok());
    absl::StatusOr<std::shared_ptr<const Model>> bad = LoadModel(path);
    ASSERT_FALSE(bad.ok()) << key;
    EXPECT_NE(bad.status().message().find("sampling." + key), std::string::npos);
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

// The tiny model with its music embedding's weights zeroed (for every frame's feature columns in `ranges`,
// or all of them): those columns add nothing whatever the music, exactly what they add when the tiny model
// reads its music mean there (normalised to 0).
std::shared_ptr<const Model> LoadDeafTinyModel(const testing::TinyModelOptions& o,
                                               const std::vector<std::pair<int, int>>& ranges = {}) {
  constexpr int f = audio::kNumFeatures;
  const int d = o.d_model;
  WeightsWriter w = testing::TinyModelWriter(o);
  const std::vector<uint8_t> bytes = w.Serialize();
  absl::StatusOr<WeightsFile> file = WeightsFile::Parse(bytes);
  EXPECT_TRUE(file.ok());
  const Tensor* weights = file->Find("seq.embed.music.weight");
  EXPECT_NE(weights, nullptr);
  std::vector<float> zeroed = weights->data;  // (d, 4F) row-major
  for (int r = 0; r < d; ++r) {
    for (int frame = 0; frame < 4; ++frame) {
      for (int c = 0; c < f; ++c) {
        const bool deaf = ranges.empty() || std::any_of(ranges.begin(), ranges.end(), [&](const auto& range) {
          return c >= range.first && c < range.second;
        });
        if (deaf) zeroed[static_cast<size_t>(r) * 4 * f + frame * f + c] = 0.0f;
      }
    }
  }
  w.Remove("seq.embed.music.weight");
  w.Add("seq.embed.music.weight", {d, 4 * f}, zeroed);
  const std::string path = ::testing::TempDir() + "/deaf_tiny.dncw";
  EXPECT_TRUE(w.WriteFile(path).ok());
  absl::StatusOr<std::shared_ptr<const Model>> m = LoadModel(path);
  EXPECT_TRUE(m.ok()) << m.status();
  return *m;
}

TEST(Session, MusicGuidanceZeroDancesFromTheMusicMeanAlone) {
  // Music guidance m: l_nm + m (l - l_nm), l_nm the lanes reading the music mean. At m = 0 the dance is
  // l_nm's: exactly the dance of the same model whose music stream is deaf (zero weights: it adds only the
  // bias, as the music mean does). A deaf model has l = l_nm, so any m dances as m = 1 there.
  testing::TinyModelOptions o;
  auto model = LoadTinyModel(o);
  auto deaf = LoadDeafTinyModel(o);
  const std::vector<float> audio = TestAudio(3.0);
  for (const bool styled : {false, true}) {  // style "none": two lanes; waltz with guidance 2: four
    auto run = [&](std::shared_ptr<const Model> m, float music_guidance) {
      SessionOptions opt = Opts(11);
      if (styled) {
        opt.style = {{"waltz", 1.0f}};
        opt.sampling.guidance = 2.0f;
      }
      opt.sampling.music_guidance = music_guidance;
      auto s = MakeSession(std::move(m), opt);
      EXPECT_EQ(s->music_guidance(), music_guidance);
      return RunStream(*s, audio, {audio.size()});
    };
    const std::vector<PoseFrame> heard = run(model, 1.0f), mean_only = run(model, 0.0f);
    ExpectSameFrames(mean_only, run(deaf, 1.0f), 0.0f);
    ExpectSameFrames(run(deaf, 0.5f), run(deaf, 1.0f), 0.0f);
    EXPECT_GT(CodesDiffer(heard, mean_only, 0) + CodesDiffer(heard, mean_only, 1), 0) << styled;
    EXPECT_GT(CodesDiffer(heard, run(model, 0.5f), 0), 0) << styled;
  }
  // A model whose music dropout replaced only some feature columns (sampling.music_guidance_features): its
  // music-mean lanes read the song's token with those columns the mean, so m = 0 is the model deaf to
  // exactly those columns.
  const std::vector<std::pair<int, int>> timbre = {{0, 52}, {53, 54}};
  testing::TinyModelOptions partial_options = o;
  partial_options.music_guidance_features = timbre;
  auto partial = LoadTinyModel(partial_options);
  ASSERT_EQ(partial->music_guidance_features(), timbre);
  auto partly_deaf = LoadDeafTinyModel(o, timbre);
  auto run = [&](std::shared_ptr<const Model> m, float music_guidance, uint64_t seed = 12) {
    SessionOptions opt = Opts(seed);
    opt.style = {{"waltz", 1.0f}};
    opt.sampling.guidance = 2.0f;
    opt.sampling.music_guidance = music_guidance;
    auto s = MakeSession(std::move(m), opt);
    return RunStream(*s, audio, {audio.size()});
  };
  const std::vector<PoseFrame> partial_mean = run(partial, 0.0f);
  ExpectSameFrames(partial_mean, run(partly_deaf, 1.0f), 0.0f);
  int differ = 0;  // not the whole token's mean (the columns kept move the logits less: several seeds)
  for (uint64_t seed = 12; seed < 16; ++seed) {
    const std::vector<PoseFrame> a = run(partial, 0.0f, seed), b = run(model, 0.0f, seed);
    differ += CodesDiffer(a, b, 0) + CodesDiffer(a, b, 1);
  }
  EXPECT_GT(differ, 0);
  // [[0, F]] is the whole token, as without the key.
  partial_options.music_guidance_features = {{0, audio::kNumFeatures}};
  ExpectSameFrames(run(LoadTinyModel(partial_options), 0.3f), run(model, 0.3f), 0.0f);
}

TEST(Session, MusicGuidanceDefaultsToTheModelsAndIsRefusedOutOfRange) {
  testing::TinyModelOptions o;
  auto plain = LoadTinyModel(o);
  o.music_guidance = 0.5;
  auto guided = LoadTinyModel(o);
  EXPECT_EQ(plain->default_music_guidance(), 1.0f);
  EXPECT_EQ(guided->default_music_guidance(), 0.5f);
  const std::vector<float> audio = TestAudio(2.5);
  auto run = [&](std::shared_ptr<const Model> m, float music_guidance) {
    SessionOptions opt = Opts(5);
    opt.sampling.music_guidance = music_guidance;
    auto s = MakeSession(std::move(m), opt);
    return std::make_pair(s->music_guidance(), RunStream(*s, audio, {audio.size()}));
  };
  const auto [m_default, by_default] = run(guided, kModelDefaultMusicGuidance);
  EXPECT_EQ(m_default, 0.5f);
  ExpectSameFrames(by_default, run(plain, 0.5f).second, 0.0f);
  const auto [m_off, off] = run(guided, 1.0f);  // explicit 1 turns it off
  EXPECT_EQ(m_off, 1.0f);
  ExpectSameFrames(off, run(plain, kModelDefaultMusicGuidance).second, 0.0f);
  EXPECT_GT(CodesDiffer(off, by_default, 0), 0);
  // Bad metadata is refused with the key named; a bad option too.
  WeightsWriter w = testing::TinyModelWriter(o);
  w.metadata()["sampling"]["music_guidance"] = -0.5;
  const std::string path = ::testing::TempDir() + "/bad_music_guidance.dncw";
  ASSERT_TRUE(w.WriteFile(path).ok());
  absl::StatusOr<std::shared_ptr<const Model>> bad = LoadModel(path);
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.status().message().find("sampling.music_guidance"), std::string::npos);
  for (const char* features : {"[]", "[[0, 0]]", "[[5, 2]]", "[[0, 109]]", "[[-1, 3]]", "[0, 52]", "[[0, 52, 1]]",
                               "[[0.5, 52]]", "\"timbre\""}) {
    WeightsWriter wf = testing::TinyModelWriter(o);
    wf.metadata()["sampling"]["music_guidance_features"] = nlohmann::json::parse(features);
    ASSERT_TRUE(wf.WriteFile(path).ok());
    bad = LoadModel(path);
    ASSERT_FALSE(bad.ok()) << features;
    EXPECT_NE(bad.status().message().find("sampling.music_guidance_features"), std::string::npos) << features;
  }
  SessionOptions opt;
  opt.sampling.music_guidance = 101.0f;
  EXPECT_FALSE(Session::Create(plain, opt).ok());
  auto s = MakeSession(plain);
  EXPECT_FALSE(s->SetSampling(opt.sampling).ok());
}

TEST(Session, MusicGuidanceSwitchesMidStreamAndSnapshotsExactly) {
  auto model = LoadTinyModel();
  const std::vector<float> audio = TestAudio(4.0);
  const size_t quarter = audio.size() / 4;
  SessionOptions opt = Opts(8);
  opt.style = {{"waltz", 1.0f}};
  opt.sampling.guidance = 2.0f;
  opt.sampling.music_guidance = 1.0f;
  auto s = MakeSession(model, opt);
  auto plain = MakeSession(model, opt);  // never switched
  ASSERT_TRUE(s->PushAudio(absl::MakeConstSpan(audio.data(), quarter)).ok());
  DrainSteps(*s);
  std::vector<PoseFrame> head;  // the frames before the switch
  s->PopFrames(&head);
  ASSERT_FALSE(head.empty());
  const int64_t bytes_off = s->StateBytes();
  SamplingOptions on = opt.sampling;
  on.music_guidance = 0.3f;
  ASSERT_TRUE(s->SetSampling(on).ok());  // the music-mean lanes start from the history of the music lanes
  ASSERT_TRUE(s->PushAudio(absl::MakeConstSpan(audio.data() + quarter, quarter)).ok());
  DrainSteps(*s);
  EXPECT_GT(s->StateBytes(), bytes_off);  // two more lanes
  absl::StatusOr<SessionSnapshot> snap = s->Snapshot();
  ASSERT_TRUE(snap.ok());
  std::vector<float> rest(audio.begin() + 2 * quarter, audio.end());
  // Off, then on again (the lanes restart from the music lanes' history), then a style change.
  auto continue_from_snapshot = [&](Session& session, size_t chunk) {
    const size_t half = rest.size() / 2;
    SamplingOptions off = on;
    off.music_guidance = 1.0f;
    EXPECT_TRUE(session.SetSampling(off).ok());
    size_t pos = 0;
    while (pos < half) {
      const size_t n = std::min(chunk, half - pos);
      EXPECT_TRUE(session.PushAudio(absl::MakeConstSpan(rest.data() + pos, n)).ok());
      pos += n;
      DrainSteps(session);
    }
    EXPECT_TRUE(session.SetSampling(on).ok());
    EXPECT_TRUE(session.SetStyle({{"tango", 1.0f}}).ok());
    std::vector<float> tail(rest.begin() + half, rest.end());
    return RunStream(session, tail, {chunk});  // pops every frame since the snapshot's
  };
  std::vector<PoseFrame> first = continue_from_snapshot(*s, 999);
  ASSERT_TRUE(s->Restore(*snap).ok());
  EXPECT_EQ(s->music_guidance(), 0.3f);
  ExpectSameFrames(first, continue_from_snapshot(*s, 4321), 0.0f);
  // The frames before the switch are the unswitched session's; after it the codes change.
  const std::vector<PoseFrame> unswitched = RunStream(*plain, audio, {audio.size()});
  ASSERT_GT(unswitched.size(), head.size() + first.size() / 2);
  ExpectSameFrames(head, std::vector<PoseFrame>(unswitched.begin(), unswitched.begin() + head.size()), 0.0f);
  EXPECT_GT(CodesDiffer(first, std::vector<PoseFrame>(unswitched.begin() + head.size(), unswitched.end()), 0), 0);
}

TEST(Session, MusicGuidanceLanesSkipStyleGuidanceForStyleNoneAndResumeExactly) {
  // Style "none" with guidance on steps the music lanes only (cond and music-mean cond). A style arriving
  // then starts the "none" lanes from them: the same as turning guidance on at that moment.
  testing::TinyModelOptions o;
  o.guidance = 3.0;
  auto model = LoadTinyModel(o);
  const std::vector<float> audio = TestAudio(3.0);
  auto switched = [&](bool guidance_from_start) {
    SessionOptions opt = Opts(9);
    opt.sampling.guidance = guidance_from_start ? kModelDefaultGuidance : 1.0f;
    opt.sampling.music_guidance = 0.5f;
    auto s = MakeSession(model, opt);
    const size_t part = audio.size() / 2;
    EXPECT_TRUE(s->PushAudio(absl::MakeConstSpan(audio.data(), part)).ok());
    DrainSteps(*s);
    EXPECT_TRUE(s->SetStyle({{"waltz", 1.0f}}).ok());
    SamplingOptions on = opt.sampling;
    on.guidance = kModelDefaultGuidance;
    EXPECT_TRUE(s->SetSampling(on).ok());
    std::vector<float> rest(audio.begin() + part, audio.end());
    return RunStream(*s, rest, {rest.size()});
  };
  ExpectSameFrames(switched(true), switched(false), 0.0f);
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

TEST(Session, CrouchGuardRuleLetsARealDipPassAndHoldsALongCrouch) {
  // A real dancer's longest crouch (2.9 s = 87 frames) does not switch the guard on; 4 s in one go does.
  double load = 0.0;
  bool active = false;
  for (int f = 0; f < 87; ++f) UpdateCrouchGuard(true, &load, &active);
  EXPECT_FALSE(active);
  for (int f = 0; f < 300; ++f) UpdateCrouchGuard(false, &load, &active);
  load = 0.0;
  int frames = 0;
  while (!active && frames < 1000) {
    UpdateCrouchGuard(true, &load, &active);
    ++frames;
  }
  EXPECT_GE(frames, 120);
  EXPECT_LE(frames, 130);
  // Then it holds for ~20 s of standing (load 120 -> 60 at exp(-1 / 900) per frame: 624 frames), not less.
  frames = 0;
  while (active && frames < 5000) {
    UpdateCrouchGuard(false, &load, &active);
    ++frames;
  }
  EXPECT_NEAR(frames, 900.0 * std::log(2.0), 10.0);
  // Repeated dips add up: 2 s down, 2 s up, ... switches it on although no dip lasts 4 s.
  load = 0.0;
  active = false;
  for (int cycle = 0; cycle < 6 && !active; ++cycle) {
    for (int f = 0; f < 60; ++f) UpdateCrouchGuard(true, &load, &active);
    for (int f = 0; f < 60 && !active; ++f) UpdateCrouchGuard(false, &load, &active);
  }
  EXPECT_TRUE(active);
}

// The shipped model on 20 s of clicks, with the foot lock and without: the same codes and, above the
// knees, the same joints; the legs bend to hold planted feet (low and slow as decoded), whose drift falls;
// bone lengths canonical.
TEST(Session, FootLockHoldsPlantedFeetAndTouchesOnlyTheLegs) {
  absl::StatusOr<std::shared_ptr<const Model>> model = LoadModel("models/default.dncw");
  ASSERT_TRUE(model.ok()) << model.status() << " (run from the source root)";
  SessionOptions opt = Opts(5);
  opt.style = {{"cha-cha", 1.0f}};
  ASSERT_TRUE(opt.sampling.foot_lock) << "on by default";
  auto on = MakeSession(*model, opt);
  opt.sampling.foot_lock = false;
  auto off = MakeSession(*model, opt);
  const std::vector<float> audio = testing::ClickAudio(20.0, 125.0);
  const std::vector<PoseFrame> a = RunStream(*on, audio, {4096});
  const std::vector<PoseFrame> b = RunStream(*off, audio, {4096});
  ASSERT_EQ(a.size(), b.size());
  ASSERT_GT(a.size(), 500u);
  constexpr int kLegs[] = {4, 5, 7, 8, 10, 11};  // knees, ankles, feet
  const Skeleton& skel = (*model)->skeleton();
  int legs_moved = 0;
  double skate_on = 0.0, skate_off = 0.0;
  int planted = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    ASSERT_EQ(a[i].upper_code, b[i].upper_code) << "frame " << i;
    ASSERT_EQ(a[i].lower_code, b[i].lower_code) << "frame " << i;
    for (int j = 0; j < kNumJoints; ++j) {
      const bool leg = std::find(std::begin(kLegs), std::end(kLegs), j) != std::end(kLegs);
      if (!leg) {
        ASSERT_EQ(a[i].positions[j], b[i].positions[j]) << "frame " << i << " joint " << j;
      }
      if (leg && (a[i].positions[j] - b[i].positions[j]).norm() > 1e-3f) ++legs_moved;
      if (j > 0) {
        ASSERT_NEAR((a[i].positions[j] - a[i].positions[skel.parents[j]]).norm(), skel.bone_lengths[j], 1e-4f)
            << "frame " << i << " joint " << j;
      }
    }
    if (i == 0) continue;
    for (int foot : {10, 11}) {  // a foot joint below 3 cm drifting slower than 0.3 m/s as decoded
      const auto horizontal = [&](const std::vector<PoseFrame>& f) {
        const Eigen::Vector3f d = f[i].positions[foot] - f[i - 1].positions[foot];
        return std::hypot(d.x(), d.z()) * 30.0;
      };
      if (b[i].positions[foot].y() > kFootLockHeightFull || horizontal(b) > 0.3) continue;
      skate_on += horizontal(a);
      skate_off += horizontal(b);
      ++planted;
    }
  }
  EXPECT_GT(legs_moved, 100);
  // The lock's state travels in snapshots: a session restored mid-song (a foot may be held right then)
  // continues exactly as the uninterrupted one.
  opt.sampling.foot_lock = true;
  auto first = MakeSession(*model, opt);
  const size_t half = audio.size() / 2;
  ASSERT_TRUE(first->PushAudio(absl::MakeConstSpan(audio.data(), half)).ok());
  DrainSteps(*first);
  std::vector<PoseFrame> resumed;
  first->PopFrames(&resumed);
  absl::StatusOr<SessionSnapshot> snap = first->Snapshot();
  ASSERT_TRUE(snap.ok());
  auto second = MakeSession(*model, opt);
  ASSERT_TRUE(second->Restore(*snap).ok());
  const std::vector<PoseFrame> rest = RunStream(*second, std::vector<float>(audio.begin() + half, audio.end()), {4096});
  resumed.insert(resumed.end(), rest.begin(), rest.end());
  ExpectSameFrames(a, resumed);
  ASSERT_GT(planted, 50);
  EXPECT_LT(skate_on, 0.7 * skate_off) << "planted feet's drift, mean m/s: " << skate_on / planted << " with the lock, "
                                       << skate_off / planted << " without";
}

TEST(Session, CrouchGuardStandsTheDancerUpAfterALongCrouch) {
  // Each code's held height is what the decoder gives after kCodeHeightSteps repeats from a fresh state.
  testing::TinyModelOptions o;
  o.height_mean = 1.0;
  o.codebook_size = 256;  // many codes: the best-standing one stands out from the frames' usual heights
  auto probe = LoadTinyModel(o);
  const int k = probe->lower_decoder().codebook_size();
  const int fpc = probe->lower_decoder().frames_per_code();
  for (int c = 0; c < k; ++c) {
    VqDecoderState state = probe->lower_decoder().NewState();
    VqDecoderScratch scratch = probe->lower_decoder().NewScratch();
    float h = 0.0f;
    for (int i = 0; i < kCodeHeightSteps; ++i) h = probe->lower_decoder().Decode(c, state, scratch)(kLowerHeightIndex, fpc - 1);
    EXPECT_NEAR(probe->lower_code_height()[c], h, 1e-5f) << "code " << c;  // batched vs alone: rounding
  }
  EXPECT_GT(probe->standing_height(), 0.5f);
  // The mean height only shifts every code's: place it so that one code of 16 stands.
  std::vector<float> sorted = probe->lower_code_height();
  std::sort(sorted.begin(), sorted.end());
  const float floor = probe->crouch_height();
  o.height_mean = 1.0 + (floor - 0.5f * (sorted[k - 1] + sorted[k - 2]));
  auto model = LoadTinyModel(o);
  const std::vector<float>& height = model->lower_code_height();
  ASSERT_EQ(std::count_if(height.begin(), height.end(), [&](float h) { return h >= floor; }), 1);
  ASSERT_EQ(model->crouched_lower_codes().size(), static_cast<size_t>(k - 1));
  EXPECT_TRUE(probe->crouched_lower_codes().empty());  // every code stands (heights ~0.9 m)
  // Every code crouched (the plain tiny model's heights are ~0): nothing is excluded, the guard does nothing.
  auto low = LoadTinyModel();
  EXPECT_LT(*std::max_element(low->lower_code_height().begin(), low->lower_code_height().end()), low->crouch_height());
  EXPECT_TRUE(low->crouched_lower_codes().empty());

  const std::vector<float> audio = TestAudio(40.0);
  auto run = [&](bool guard) {
    SamplingOptions sampling = Sampling(1.0f);
    sampling.crouch_guard = guard;
    auto s = MakeSession(model, Opts(3, sampling));
    return RunStream(*s, audio, {4096});
  };
  // Replays the guard's rule on the frames (step t's frames are [4t, 4t + 4) of the output, the pelvis is
  // the decoded height): steps taken while the guard was on, and whether each of them sampled a standing
  // lower code; the longest run of crouched frames.
  struct Replay {
    int guarded_steps = 0, standing = 0;
    int64_t longest = 0;
  };
  auto replay = [&](const std::vector<PoseFrame>& frames) {
    Replay r;
    double load = 0.0;
    bool active = false;
    int64_t crouched = 0;
    for (size_t i = 0; i + 4 <= frames.size(); i += 4) {
      if (active) {
        ++r.guarded_steps;
        r.standing += height[frames[i].lower_code] >= floor;
      }
      for (size_t f = i; f < i + 4; ++f) {
        const bool below = frames[f].positions[0].y() < floor;
        UpdateCrouchGuard(below, &load, &active);
        crouched = below ? crouched + 1 : 0;
        r.longest = std::max(r.longest, crouched);
      }
    }
    return r;
  };
  const std::vector<PoseFrame> off_frames = run(false);
  const Replay off = replay(off_frames), on = replay(run(true));
  ASSERT_GT(off.guarded_steps, 10);  // without the guard this model crouches for long stretches
  EXPECT_LT(off.standing, off.guarded_steps);
  ASSERT_GT(on.guarded_steps, 0);
  EXPECT_EQ(on.standing, on.guarded_steps);  // with it every such step samples the standing code
  EXPECT_LT(on.longest, off.longest);

  // The crouch count is part of the snapshot: restored mid-stream, the session continues exactly.
  SamplingOptions sampling = Sampling(1.0f);
  auto a = MakeSession(model, Opts(3, sampling));
  const size_t part = audio.size() / 2 + 77;
  ASSERT_TRUE(a->PushAudio(absl::MakeConstSpan(audio.data(), part)).ok());
  DrainSteps(*a);
  absl::StatusOr<SessionSnapshot> snap = a->Snapshot();
  ASSERT_TRUE(snap.ok());
  std::vector<float> rest(audio.begin() + part, audio.end());
  const std::vector<PoseFrame> first = RunStream(*a, rest, {1000});
  auto b = MakeSession(model, Opts(3, sampling));
  ASSERT_TRUE(b->Restore(*snap).ok());
  ExpectSameFrames(first, RunStream(*b, rest, {2500}));
}


// ---- Tempo-normalised models (Model::tempo_reference_bpm() > 0, docs/model.md section 8) ----

std::shared_ptr<const Model> WarpedTinyModel(double reference_bpm = 105.0) {
  testing::TinyModelOptions o;
  o.tempo_reference_bpm = reference_bpm;
  return LoadTinyModel(o);
}

TEST(WarpedSession, EmitsContiguousFramesCoveringTheAudio) {
  auto model = WarpedTinyModel();
  ASSERT_EQ(model->tempo_reference_bpm(), 105.0);
  auto s = MakeSession(model);
  const std::vector<PoseFrame> frames = RunStream(*s, testing::ClickAudio(6.0, 140.0), {4000});
  // 6 s = 45 periods = frames 0..179; poses from frame 4 on, every frame once, in order.
  ASSERT_EQ(frames.size(), 180u - 4u);
  for (size_t i = 0; i < frames.size(); ++i) {
    ASSERT_EQ(frames[i].index, static_cast<int64_t>(i) + 4);
    ASSERT_DOUBLE_EQ(frames[i].time_s, frames[i].index / 30.0);
  }
}

TEST(WarpedSession, ChunkingInvariance) {
  auto model = WarpedTinyModel();
  const std::vector<float> audio = testing::ClickAudio(5.0, 95.0);
  auto a = MakeSession(model, Opts(3, Sampling(1.0f)));
  auto b = MakeSession(model, Opts(3, Sampling(1.0f)));
  auto c = MakeSession(model, Opts(3, Sampling(1.0f)));
  const std::vector<PoseFrame> whole = RunStream(*a, audio, {audio.size()});
  ExpectSameFrames(whole, RunStream(*b, audio, {1, 799, 3200, 17}));
  ExpectSameFrames(whole, RunStream(*c, audio, {24000}));
}

TEST(WarpedSession, StepsFollowTheMusicTempo) {
  // Over the last 10 s of a 20 s click track (the beat tracker has settled), warped steps advance at
  // fold(tempo) / reference: at 140 BPM 4/3 warped frames per real frame, at 90 BPM 6/7.
  auto model = WarpedTinyModel(105.0);
  auto steps_in_second_half = [&](double bpm) {
    auto s = MakeSession(model);
    return StepsInSecondHalf(*s, testing::ClickAudio(20.0, bpm));
  };
  const double fast = steps_in_second_half(140.0), slow = steps_in_second_half(90.0);
  // 300 real frames / 4 frames per step x rate.
  EXPECT_NEAR(fast, 75.0 * 140.0 / 105.0, 2.0);
  EXPECT_NEAR(slow, 75.0 * 90.0 / 105.0, 2.0);
  // A fixed-rate model takes 75 steps whatever the tempo.
  auto fixed = MakeSession(LoadTinyModel());
  const std::vector<float> audio = testing::ClickAudio(10.0, 140.0);
  ASSERT_TRUE(fixed->PushAudio(audio).ok());
  DrainSteps(*fixed);
  EXPECT_EQ(fixed->steps_done(), 75);
}

TEST(WarpedSession, IsCausal) {
  // Frame m depends on audio before m / 30 s only (declared lookahead 0): perturbing the audio from
  // sample X on changes no frame with m * 800 <= X.
  auto model = WarpedTinyModel();
  std::vector<float> audio = testing::ClickAudio(6.0, 120.0);
  std::vector<float> changed = audio;
  const size_t from = 3 * 24000 + 123;
  std::mt19937 gen(5);
  std::uniform_real_distribution<float> noise(-0.5f, 0.5f);
  for (size_t i = from; i < changed.size(); ++i) changed[i] = noise(gen);
  auto a = MakeSession(model, Opts(2, Sampling(0.0f)));
  auto b = MakeSession(model, Opts(2, Sampling(0.0f)));
  const std::vector<PoseFrame> fa = RunStream(*a, audio, {3000});
  const std::vector<PoseFrame> fb = RunStream(*b, changed, {3000});
  ASSERT_EQ(fa.size(), fb.size());
  size_t compared = 0;
  bool later_differs = false;
  for (size_t i = 0; i < fa.size(); ++i) {
    const bool before = fa[i].index * 800 <= static_cast<int64_t>(from);
    float diff = 0.0f;
    for (int j = 0; j < 24; ++j) diff = std::max(diff, (fa[i].positions[j] - fb[i].positions[j]).norm());
    if (before) {
      ASSERT_EQ(diff, 0.0f) << "frame " << fa[i].index;
      ++compared;
    } else if (diff > 0.0f) {
      later_differs = true;
    }
  }
  EXPECT_GT(compared, 80u);
  EXPECT_TRUE(later_differs);  // the perturbation reaches the dance (else the test proves nothing)
}

TEST(WarpedSession, SnapshotRestoreContinuesExactly) {
  auto model = WarpedTinyModel();
  const std::vector<float> audio = testing::ClickAudio(5.0, 130.0);
  const size_t part = audio.size() / 2 + 321;
  auto s = MakeSession(model, Opts(8, Sampling(0.8f, 6)));
  ASSERT_TRUE(s->PushAudio(absl::MakeConstSpan(audio.data(), part)).ok());
  DrainSteps(*s);
  absl::StatusOr<SessionSnapshot> snap = s->Snapshot();
  ASSERT_TRUE(snap.ok());
  std::vector<float> rest(audio.begin() + part, audio.end());
  const std::vector<PoseFrame> first = RunStream(*s, rest, {1000});
  auto fresh = MakeSession(model, Opts(8, Sampling(0.8f, 6)));
  ASSERT_TRUE(fresh->Restore(*snap).ok());
  ExpectSameFrames(first, RunStream(*fresh, rest, {4321}));
  s->Reset();
  auto again = MakeSession(model, Opts(8, Sampling(0.8f, 6)));
  ExpectSameFrames(RunStream(*s, audio, {5000}), RunStream(*again, audio, {777}));
}

TEST(WarpedSession, StepBatchMatchesSteppingAlone) {
  // Waltz sessions of a model with a dance period and a default lock: locked, locked with guidance, unlocked.
  testing::TinyModelOptions o;
  o.tempo_reference_bpm = 105.0;
  o.style_reference_bpm = {{"waltz", 90.0}};
  o.dance_period_beats = {{"waltz", 1.0}};  // 5 steps: the lock engages within the 4 s
  o.period_lock = 4.0;
  auto model = LoadTinyModel(o);
  const std::vector<float> audio = testing::ClickAudio(4.0, 100.0);
  auto options = [](int i) {
    SessionOptions opt = Opts(10 + i, Sampling(1.0f, 0, i == 1 ? 2.0f : 1.0f));
    if (i == 2) opt.sampling.period_lock = 0.0f;
    opt.style = {{"waltz", 1.0f}};
    return opt;
  };
  std::vector<std::vector<PoseFrame>> alone;
  for (int i = 0; i < 3; ++i) {
    auto s = MakeSession(model, options(i));
    alone.push_back(RunStream(*s, audio, {2400}));
  }
  std::vector<std::unique_ptr<Session>> sessions;
  std::vector<Session*> ptrs;
  for (int i = 0; i < 3; ++i) {
    sessions.push_back(MakeSession(model, options(i)));
    ptrs.push_back(sessions.back().get());
  }
  EXPECT_EQ(ptrs[0]->period_lock(), 4.0f);
  EXPECT_EQ(ptrs[2]->period_lock(), 0.0f);
  for (size_t pos = 0; pos < audio.size(); pos += 2400) {
    const size_t n = std::min<size_t>(2400, audio.size() - pos);
    for (Session* s : ptrs) ASSERT_TRUE(s->PushAudio(absl::MakeConstSpan(audio.data() + pos, n)).ok());
    while (ptrs[0]->StepsReady() > 0) ASSERT_TRUE(StepBatch(ptrs).ok());
  }
  for (Session* s : ptrs) {
    s->EndOfAudio();
    DrainSteps(*s);
  }
  for (int i = 0; i < 3; ++i) {
    std::vector<PoseFrame> out;
    ptrs[i]->PopFrames(&out);
    ExpectSameFrames(alone[i], out, 1e-4f);
  }
}

TEST(WarpedSession, EachStyleHasItsOwnReferenceTempo) {
  // waltz R = 87, tango R = 128: a 140 BPM click track is a tango at rate 140 / 128 and, folded into the
  // waltz octave [61.5, 123) (140 is beyond its 8 % hysteresis), a 70 BPM waltz at rate 70 / 87; a mix
  // uses the geometric mean of the references; "none" the default 105.
  testing::TinyModelOptions o;
  o.tempo_reference_bpm = 105.0;
  o.style_reference_bpm = {{"waltz", 87.0}, {"tango", 128.0}};
  auto model = LoadTinyModel(o);
  auto steps_in_second_half = [&](std::vector<std::pair<std::string, float>> style) {
    SessionOptions opt;
    opt.style = std::move(style);
    auto s = MakeSession(model, opt);
    return StepsInSecondHalf(*s, testing::ClickAudio(20.0, 140.0));
  };
  EXPECT_NEAR(steps_in_second_half({{"tango", 1.0f}}), 75.0 * 140.0 / 128.0, 2.0);
  EXPECT_NEAR(steps_in_second_half({{"waltz", 1.0f}}), 75.0 * 70.0 / 87.0, 2.0);
  EXPECT_NEAR(steps_in_second_half({}), 75.0 * 140.0 / 105.0, 2.0);
  // 50/50 mix: R = sqrt(87 * 128) = 105.5; 140 stays in [74.6, 149.2).
  EXPECT_NEAR(steps_in_second_half({{"waltz", 0.5f}, {"tango", 0.5f}}), 75.0 * 140.0 / std::sqrt(87.0 * 128.0),
              2.0);
}

// Two sessions fed the same audio in lockstep, 800 samples at a time, both switched to tango halfway (from
// the next step on): on_step(token_a, token_b, tango) sees their last warped music tokens after every step.
// Returns `a`'s snapshot, taken right after the switch.
constexpr size_t kLockstepChunk = 800;

size_t LockstepSwitch(const std::vector<float>& audio) {
  return audio.size() / 2 / kLockstepChunk * kLockstepChunk;
}

std::optional<SessionSnapshot> StepInLockstep(
    Session& a, Session& b, const std::vector<float>& audio,
    const std::function<void(const std::vector<float>&, const std::vector<float>&, bool)>& on_step) {
  std::optional<SessionSnapshot> snap;
  for (size_t pos = 0; pos + kLockstepChunk <= audio.size(); pos += kLockstepChunk) {
    if (pos == LockstepSwitch(audio)) {
      EXPECT_TRUE(a.SetStyle({{"tango", 1.0f}}).ok());
      EXPECT_TRUE(b.SetStyle({{"tango", 1.0f}}).ok());
      absl::StatusOr<SessionSnapshot> s = a.Snapshot();
      if (!s.ok()) {
        ADD_FAILURE() << s.status();
        return std::nullopt;
      }
      snap = *s;
    }
    const bool tango = snap.has_value();
    EXPECT_TRUE(a.PushAudio(absl::MakeConstSpan(audio.data() + pos, kLockstepChunk)).ok());
    EXPECT_TRUE(b.PushAudio(absl::MakeConstSpan(audio.data() + pos, kLockstepChunk)).ok());
    while (a.StepsReady() > 0) {
      if (b.StepsReady() <= 0) {
        ADD_FAILURE() << "the second session has no step ready where the first has";
        return std::nullopt;
      }
      EXPECT_TRUE(a.Step().ok());
      EXPECT_TRUE(b.Step().ok());
      on_step(a.last_warped_music_token(), b.last_warped_music_token(), tango);
    }
  }
  return snap;
}

TEST(WarpedSession, FoldTempoShowsTheSongAtTheStylesReference) {
  // time_base.fold_tempo: the tempogram and tempo features of each warped frame are folded with its source
  // frame's clock rate (audio::FoldTempoFeatures), so a 140 BPM click plays at the waltz's 87 BPM (one
  // octave down: 70 BPM folded) and then, after a mid-stream style change, at the tango's 128; the rest of
  // each row is the source frame's, as without the fold.
  testing::TinyModelOptions o;
  o.tempo_reference_bpm = 105.0;
  o.style_reference_bpm = {{"waltz", 87.0}, {"tango", 128.0}};
  auto plain_model = LoadTinyModel(o);
  o.fold_tempo = "true";
  auto fold_model = LoadTinyModel(o);
  ASSERT_TRUE(fold_model->fold_tempo());
  EXPECT_FALSE(plain_model->fold_tempo());
  SessionOptions opt = Opts(4, Sampling(1.0f));
  opt.style = {{"waltz", 1.0f}};
  auto fold = MakeSession(fold_model, opt);
  auto plain = MakeSession(plain_model, opt);
  const std::vector<float> audio = testing::ClickAudio(12.0, 140.0);
  const int fps = fold_model->config().frames_per_step;
  int checked = 0, plain_off_reference = 0;
  const std::optional<SessionSnapshot> snap = StepInLockstep(
      *fold, *plain, audio,
      [&](const std::vector<float>& tf, const std::vector<float>& tp, bool tango) {
        ASSERT_EQ(tf.size(), static_cast<size_t>(fps * audio::kNumFeatures));
        for (int f = 0; f < fps; ++f) {
          const float* rf = tf.data() + f * audio::kNumFeatures;
          const float* rp = tp.data() + f * audio::kNumFeatures;
          // The song's tempo and the clock's rate (the tempo the fold removed).
          const double song_bpm = 120.0 * std::exp2(rp[audio::kTempoIndex]);
          const double rate =
              std::exp2(static_cast<double>(rp[audio::kTempoIndex]) - rf[audio::kTempoIndex]);
          ASSERT_GT(rate, 1.0 / std::sqrt(2.0) / 1.08);
          ASSERT_LT(rate, std::sqrt(2.0) * 1.08);
          // The folded tempo is in the reference's octave class: the reference times a power of 2.
          const double ref = tango ? 128.0 : 87.0;
          const double octaves = std::log2(120.0 * std::exp2(rf[audio::kTempoIndex]) / ref);
          ASSERT_NEAR(octaves, std::round(octaves), 1e-4) << "song at " << song_bpm << " BPM";
          plain_off_reference +=
              std::fabs(std::log2(song_bpm / ref) - std::round(std::log2(song_bpm / ref))) > 0.05;
          std::vector<float> expected(rp, rp + audio::kNumFeatures);
          audio::FoldTempoFeatures(rate, expected.data());
          for (int i = 0; i < audio::kNumFeatures; ++i) {
            if (i == audio::kTempoIndex) continue;
            if (i >= audio::kTempogramBegin && i < audio::kTempogramBegin + audio::kNumTempogram) {
              ASSERT_NEAR(rf[i], expected[i], 1e-4) << i;
            } else {
              ASSERT_EQ(rf[i], rp[i]) << i;
            }
          }
          ++checked;
        }
      });
  EXPECT_GT(checked, 4 * 80);
  EXPECT_GT(plain_off_reference, checked / 2);  // unfolded, the click is not at the reference's octaves
  // A snapshot restored into a new session continues exactly (the rates travel with the warped frames).
  ASSERT_TRUE(snap.has_value());
  auto original = MakeSession(fold_model, opt);
  auto restored = MakeSession(fold_model, opt);
  ASSERT_TRUE(original->Restore(*snap).ok());
  ASSERT_TRUE(restored->Restore(*snap).ok());
  std::vector<float> rest(audio.begin() + LockstepSwitch(audio), audio.end());
  ExpectSameFrames(RunStream(*original, rest, {kLockstepChunk}), RunStream(*restored, rest, {3 * kLockstepChunk}));
  // The metadata key must be a boolean.
  o.fold_tempo = "1";
  const std::string path = ::testing::TempDir() + "/bad_fold_tempo.dncw";
  ASSERT_TRUE(testing::TinyModelWriter(o).WriteFile(path).ok());
  absl::StatusOr<std::shared_ptr<const Model>> m = LoadModel(path);
  ASSERT_FALSE(m.ok());
  EXPECT_TRUE(absl::StrContains(m.status().message(), "fold_tempo must be true or false")) << m.status();
  o.fold_tempo = "false";
  ASSERT_TRUE(testing::TinyModelWriter(o).WriteFile(path).ok());
  m = LoadModel(path);
  ASSERT_TRUE(m.ok()) << m.status();
  EXPECT_FALSE((*m)->fold_tempo());
}

TEST(WarpedSession, BarClockReplacesTheTrackersBarPhase) {
  // Bar clock: 4 beats per bar, waltz 3 (waltz R = 87, tango R = 128). The bar phase of warped frame j is
  // frac(j / L), L = beats * 1800 / R; every other feature is the source frame's, as without the clock.
  testing::TinyModelOptions o;
  o.tempo_reference_bpm = 105.0;
  o.style_reference_bpm = {{"waltz", 87.0}, {"tango", 128.0}};
  auto plain_model = LoadTinyModel(o);
  o.bar_clock_beats = 4;
  o.style_beats_per_bar = {{"waltz", 3}};
  auto bar_model = LoadTinyModel(o);
  ASSERT_TRUE(bar_model->bar_clock());
  EXPECT_EQ(bar_model->StyleBeatsPerBar(*bar_model->StyleIndex("waltz")), 3);
  EXPECT_EQ(bar_model->StyleBeatsPerBar(*bar_model->StyleIndex("tango")), 4);
  EXPECT_FALSE(plain_model->bar_clock());
  SessionOptions opt = Opts(4, Sampling(1.0f));
  opt.style = {{"waltz", 1.0f}};
  auto bar = MakeSession(bar_model, opt);
  auto plain = MakeSession(plain_model, opt);
  const std::vector<float> audio = testing::ClickAudio(8.0, 140.0);
  const int fps = bar_model->config().frames_per_step;
  int checked = 0, tracker_differs = 0;
  // Mid-stream style change: tango's metre and reference from the next step on; then a snapshot.
  const std::optional<SessionSnapshot> snap = StepInLockstep(
      *bar, *plain, audio,
      [&](const std::vector<float>& tb, const std::vector<float>& tp, bool tango) {
        ASSERT_EQ(tb.size(), static_cast<size_t>(fps * audio::kNumFeatures));
        const double period = tango ? 4 * 1800.0 / 128.0 : 3 * 1800.0 / 87.0;
        for (int f = 0; f < fps; ++f) {
          const int64_t j = (bar->steps_done() - 1) * fps + f;
          const double x = j / period - std::floor(j / period);
          const float* rb = tb.data() + f * audio::kNumFeatures;
          const float* rp = tp.data() + f * audio::kNumFeatures;
          ASSERT_NEAR(rb[audio::kBarPhaseCosIndex], std::cos(2.0 * M_PI * x), 1e-6)
              << "warped frame " << j;
          ASSERT_NEAR(rb[audio::kBarPhaseSinIndex], std::sin(2.0 * M_PI * x), 1e-6)
              << "warped frame " << j;
          for (int i = 0; i < audio::kNumFeatures; ++i) {
            if (i != audio::kBarPhaseCosIndex && i != audio::kBarPhaseSinIndex) {
              ASSERT_EQ(rb[i], rp[i]) << i;
            }
          }
          tracker_differs +=
              std::fabs(rp[audio::kBarPhaseCosIndex] - rb[audio::kBarPhaseCosIndex]) > 1e-3f;
          ++checked;
        }
      });
  EXPECT_GT(checked, 4 * 60);
  EXPECT_GT(tracker_differs, checked / 2);  // the tracker's bar phase is another signal
  // A snapshot (taken as tango) restored into a session created as a waltz continues exactly.
  ASSERT_TRUE(snap.has_value());
  auto restored = MakeSession(bar_model, opt);
  ASSERT_TRUE(restored->Restore(*snap).ok());
  auto original = MakeSession(bar_model, opt);
  ASSERT_TRUE(original->Restore(*snap).ok());
  std::vector<float> rest(audio.begin() + LockstepSwitch(audio), audio.end());
  const std::vector<PoseFrame> a = RunStream(*original, rest, {kLockstepChunk});
  ExpectSameFrames(a, RunStream(*restored, rest, {3 * kLockstepChunk}));
  // And the snapshot's bar clock is tango's, not the creating style's: the first token after restore.
  auto probe = MakeSession(bar_model, opt);
  ASSERT_TRUE(probe->Restore(*snap).ok());
  ASSERT_TRUE(probe->PushAudio(absl::MakeConstSpan(rest.data(), rest.size())).ok());
  ASSERT_GT(probe->StepsReady(), 0);
  ASSERT_TRUE(probe->Step().ok());
  const int64_t j = (probe->steps_done() - 1) * fps;
  const double x = j / (4 * 1800.0 / 128.0) - std::floor(j / (4 * 1800.0 / 128.0));
  EXPECT_NEAR(probe->last_warped_music_token()[audio::kBarPhaseCosIndex], std::cos(2.0 * M_PI * x), 1e-6);
}

// Every step's (upper, lower) codes of a session on `audio` (then EndOfAudio) with `style` and lock weight
// `lock`, sampling at temperature 1 with seed 5.
std::vector<std::pair<int, int>> LockedCodes(std::shared_ptr<const Model> m, float lock, const std::string& style,
                                             const std::vector<float>& audio) {
  SamplingOptions sampling = Sampling(1.0f);
  sampling.period_lock = lock;
  SessionOptions opt = Opts(5, sampling);
  opt.style = {{style, 1.0f}};
  auto s = MakeSession(std::move(m), opt);
  EXPECT_TRUE(s->PushAudio(absl::MakeConstSpan(audio)).ok());
  s->EndOfAudio();
  std::vector<std::pair<int, int>> codes;
  while (s->StepsReady() > 0) {
    EXPECT_TRUE(s->Step().ok());
    codes.push_back(s->last_codes());
  }
  return codes;
}

TEST(WarpedSession, PeriodLockRepeatsTheCodesOfOneDancePeriodAgo) {
  // Waltz: 3 beats at R = 90 BPM = 60 warped frames = 15 steps exactly; tango: 2 beats at 120 = 7.5 steps.
  testing::TinyModelOptions o;
  o.tempo_reference_bpm = 105.0;
  o.style_reference_bpm = {{"waltz", 90.0}, {"tango", 120.0}};
  auto plain_model = LoadTinyModel(o);
  o.dance_period_beats = {{"waltz", 3.0}, {"tango", 2.0}};
  auto model = LoadTinyModel(o);
  EXPECT_DOUBLE_EQ(model->StyleDancePeriodBeats(*model->StyleIndex("waltz")), 3.0);
  EXPECT_DOUBLE_EQ(model->StyleDancePeriodBeats(*model->StyleIndex("none")), 0.0);
  EXPECT_FALSE(plain_model->has_dance_periods());
  const std::vector<float> audio = testing::ClickAudio(12.0, 100.0);
  // Fraction of steps whose code (each stream) equals the code `lag` steps earlier.
  auto repeat_fraction = [&](std::shared_ptr<const Model> m, float lock, const std::string& style, int lag) {
    const std::vector<std::pair<int, int>> codes = LockedCodes(std::move(m), lock, style, audio);
    int same = 0, n = 0;
    for (size_t t = 2 * lag; t < codes.size(); ++t, ++n) {
      same += codes[t].first == codes[t - lag].first;
      same += codes[t].second == codes[t - lag].second;
    }
    return n > 0 ? same / (2.0 * n) : 0.0;
  };
  const double free_running = repeat_fraction(model, 0.0f, "waltz", 15);
  const double locked = repeat_fraction(model, 100.0f, "waltz", 15);
  // The tiny random model repeats about a third of its codes by itself (few codes, slowly varying
  // features); the lock makes it nearly all.
  EXPECT_LT(free_running, 0.5);
  EXPECT_GT(locked, 0.95);
  // Lock 0 is exactly the model without dance periods; a model without them ignores the lock.
  EXPECT_EQ(repeat_fraction(plain_model, 0.0f, "waltz", 15), free_running);
  EXPECT_EQ(repeat_fraction(plain_model, 100.0f, "waltz", 15), free_running);
  // A fractional period (tango, 7.5 steps) locks at the whole number of steps nearest to it (8).
  EXPECT_GT(repeat_fraction(model, 100.0f, "tango", 8), 0.95);
  EXPECT_LT(repeat_fraction(model, 0.0f, "tango", 8), 0.5);
}

TEST(WarpedSession, PeriodLockReachesBackEachStreamsNumberOfPeriods) {
  // time_base.period_lock_periods {"upper": 1, "lower": 2}: waltz (3 beats at 90 BPM = 15 steps) locks the
  // upper body at 15 steps and the lower at 30; tango (2 beats at 120 = 7.5 steps) at 8 and 2 x 8 = 16 (not
  // round(15.0): the lower body stays in phase with the upper). 64 codes: the movement rule asks for 15 distinct codes
  // in a 30-step window, which the 16 codes of the usual tiny model rarely reach.
  testing::TinyModelOptions o;
  o.codebook_size = 64;
  o.tempo_reference_bpm = 105.0;
  o.style_reference_bpm = {{"waltz", 90.0}, {"tango", 120.0}};
  o.dance_period_beats = {{"waltz", 3.0}, {"tango", 2.0}};
  auto one_period = LoadTinyModel(o);
  o.upper_lock_periods = 1;
  o.lower_lock_periods = 1;
  auto explicit_one = LoadTinyModel(o);
  o.lower_lock_periods = 2;
  auto model = LoadTinyModel(o);
  EXPECT_EQ(one_period->period_lock_periods(0), 1);
  EXPECT_EQ(one_period->period_lock_periods(1), 1);
  EXPECT_EQ(model->period_lock_periods(0), 1);
  EXPECT_EQ(model->period_lock_periods(1), 2);
  const std::vector<float> audio = testing::ClickAudio(20.0, 100.0);
  auto codes_of = [&](std::shared_ptr<const Model> m, const std::string& style) {
    return LockedCodes(std::move(m), 100.0f, style, audio);
  };
  // Fraction of steps from `from` on whose code of `stream` equals the code `lag` steps earlier.
  auto repeats = [](const std::vector<std::pair<int, int>>& codes, int stream, size_t lag, size_t from) {
    int same = 0, n = 0;
    for (size_t t = from; t < codes.size(); ++t, ++n) {
      same += stream == 0 ? codes[t].first == codes[t - lag].first : codes[t].second == codes[t - lag].second;
    }
    EXPECT_GT(n, 40);
    return n > 0 ? static_cast<double>(same) / n : 0.0;
  };
  const auto waltz = codes_of(model, "waltz");
  EXPECT_GT(repeats(waltz, 0, 15, 60), 0.95);
  EXPECT_GT(repeats(waltz, 1, 30, 60), 0.95);
  EXPECT_LT(repeats(waltz, 1, 15, 60), 0.5);  // the lower body's figure is two periods long
  const auto tango = codes_of(model, "tango");
  EXPECT_GT(repeats(tango, 0, 8, 60), 0.95);
  EXPECT_GT(repeats(tango, 1, 16, 60), 0.95);
  EXPECT_LT(repeats(tango, 1, 15, 60), 0.5);
  // One period for the lower body too: at 15 steps; and {1, 1} is the model without the key.
  const auto waltz_one = codes_of(one_period, "waltz");
  EXPECT_GT(repeats(waltz_one, 1, 15, 60), 0.95);
  EXPECT_EQ(codes_of(explicit_one, "waltz"), waltz_one);
  EXPECT_NE(waltz, waltz_one);
}

TEST(WarpedSession, PeriodLockRepeatsMovementNotStillness) {
  // The lock applies to a stream only if at least half of the last period's steps brought a new code.
  std::deque<std::pair<int, int>> history;
  for (int t = 0; t < 16; ++t) history.emplace_back(t, t % 2 == 0 ? 3 : 4);  // upper moves, lower flips
  EXPECT_TRUE(PeriodMoved(history, 0, 16, 512));
  EXPECT_FALSE(PeriodMoved(history, 1, 16, 512));
  EXPECT_TRUE(PeriodMoved(history, 1, 4, 512));   // 2 distinct of 4: half
  EXPECT_FALSE(PeriodMoved(history, 1, 5, 512));  // 2 of 5
  for (int t = 0; t < 8; ++t) history.emplace_back(7, 7);  // then held for 8 steps
  EXPECT_FALSE(PeriodMoved(history, 0, 8, 512));
  EXPECT_TRUE(PeriodMoved(history, 0, 16, 512));  // 8 + 1 distinct of 16
  EXPECT_FALSE(PeriodMoved(history, 0, 2, 512));  // a short period of one held code is still
  EXPECT_FALSE(PeriodMoved(history, 0, 1, 512));
}

TEST(WarpedSession, PeriodLockDoesNotRepeatATurn) {
  // The heading at the start of each step; the lower body's lock is released after a period that turned
  // the body by more than half a turn (either way), so a repeated turn cannot become an endless spin.
  std::deque<double> headings;
  EXPECT_FALSE(PeriodTurned(headings, 4));
  for (int t = 0; t <= 4; ++t) headings.push_back(0.7 * t);  // 2.8 rad in 4 steps
  EXPECT_FALSE(PeriodTurned(headings, 4));
  EXPECT_FALSE(PeriodTurned(headings, 5));  // needs lag + 1 entries
  headings.push_back(0.7 * 5);              // 2.8 rad over the last 4, 3.5 over the last 5
  EXPECT_FALSE(PeriodTurned(headings, 4));
  EXPECT_TRUE(PeriodTurned(headings, 5));
  EXPECT_FALSE(PeriodTurned(headings, 0));
  for (double& h : headings) h = -h;  // turning the other way counts the same
  EXPECT_TRUE(PeriodTurned(headings, 5));
  headings.push_back(headings.front());  // back where it started 6 steps ago: no net turn
  EXPECT_FALSE(PeriodTurned(headings, 6));
  EXPECT_FALSE(PeriodTurned(headings, 6, 0.0));
  EXPECT_TRUE(PeriodTurned(headings, 1, 1.0));
  EXPECT_GT(kPeriodLockMaxTurn, 3.14);
  EXPECT_LT(kPeriodLockMaxTurn, 3.15);
}

TEST(WarpedSession, PeriodLockReleasesTheLowerBodyAfterATurn) {
  // Waltz: 3 beats at 90 BPM = 15 steps = 60 frames. A lower decoder whose yaw rate averages 0.1 rad per
  // frame turns ~6 rad per period, more than half a turn: the lower body's lock is released (else it would
  // repeat the turn for ever) while the upper body's still repeats its period.
  testing::TinyModelOptions o;
  o.tempo_reference_bpm = 105.0;
  o.style_reference_bpm = {{"waltz", 90.0}};
  o.dance_period_beats = {{"waltz", 3.0}};
  o.yaw_rate_mean = 0.1;
  auto spinning = LoadTinyModel(o);
  const std::vector<float> audio = testing::ClickAudio(12.0, 100.0);
  SamplingOptions sampling = Sampling(1.0f);
  sampling.period_lock = 100.0f;
  SessionOptions opt = Opts(5, sampling);
  opt.style = {{"waltz", 1.0f}};
  auto s = MakeSession(spinning, opt);
  ASSERT_TRUE(s->PushAudio(absl::MakeConstSpan(audio)).ok());
  s->EndOfAudio();
  std::vector<std::pair<int, int>> codes;
  while (s->StepsReady() > 0) {
    ASSERT_TRUE(s->Step().ok());
    codes.push_back(s->last_codes());
  }
  int same_upper = 0, same_lower = 0, n = 0;
  for (size_t t = 30; t < codes.size(); ++t, ++n) {
    same_upper += codes[t].first == codes[t - 15].first;
    same_lower += codes[t].second == codes[t - 15].second;
  }
  ASSERT_GT(n, 30);
  EXPECT_GT(same_upper, 0.95 * n);
  EXPECT_LT(same_lower, 0.5 * n);
  // The heading history is part of the snapshot: restored mid-stream, the session continues exactly (without
  // it the guard would not fire for a period and the lower codes would lock).
  auto a = MakeSession(spinning, opt);
  const size_t part = audio.size() / 2 + 77;
  ASSERT_TRUE(a->PushAudio(absl::MakeConstSpan(audio.data(), part)).ok());
  DrainSteps(*a);
  absl::StatusOr<SessionSnapshot> snap = a->Snapshot();
  ASSERT_TRUE(snap.ok());
  ASSERT_GE(snap->sampling.heading_history.size(), 16u);
  std::vector<float> rest(audio.begin() + part, audio.end());
  const std::vector<PoseFrame> first = RunStream(*a, rest, {1000});
  auto b = MakeSession(spinning, opt);
  ASSERT_TRUE(b->Restore(*snap).ok());
  ExpectSameFrames(first, RunStream(*b, rest, {2500}));
  SessionSnapshot forgetful = *snap;
  forgetful.sampling.heading_history.clear();
  auto c = MakeSession(spinning, opt);
  ASSERT_TRUE(c->Restore(forgetful).ok());
  const std::vector<PoseFrame> other = RunStream(*c, rest, {2500});
  ASSERT_EQ(other.size(), first.size());
  EXPECT_GT(CodesDiffer(first, other, 1), 0);
}

TEST(Session, GuidanceIsSkippedForStyleNoneAndResumesExactly) {
  // Style "none": both lanes would be the same computation, so guidance costs nothing and changes nothing.
  testing::TinyModelOptions o;
  o.guidance = 3.0;
  auto model = LoadTinyModel(o);
  const std::vector<float> audio = TestAudio(3.0);
  auto run = [&](float w) {
    SessionOptions opt = Opts(6);
    opt.sampling.guidance = w;
    auto s = MakeSession(model, opt);
    const int64_t bytes_before = s->StateBytes();
    auto frames = RunStream(*s, audio, {audio.size()});
    return std::make_tuple(s->guidance(), bytes_before, frames);
  };
  const auto [w3, bytes3, none3] = run(kModelDefaultGuidance);
  const auto [w1, bytes1, none1] = run(1.0f);
  EXPECT_EQ(w3, 3.0f);
  EXPECT_EQ(w1, 1.0f);
  EXPECT_EQ(bytes3, bytes1);  // no unconditional lane kept
  ExpectSameFrames(none3, none1, 0.0f);
  // Switching from "none" to a style with guidance on starts the unconditional lane from the conditional
  // one (which was the "none" lane): the same as turning guidance on at that moment.
  auto switched = [&](bool guidance_from_start) {
    SessionOptions opt = Opts(6);
    opt.sampling.guidance = guidance_from_start ? kModelDefaultGuidance : 1.0f;
    auto s = MakeSession(model, opt);
    const size_t part = audio.size() / 2;
    EXPECT_TRUE(s->PushAudio(absl::MakeConstSpan(audio.data(), part)).ok());
    DrainSteps(*s);
    EXPECT_TRUE(s->SetStyle({{"waltz", 1.0f}}).ok());
    SamplingOptions on = opt.sampling;
    on.guidance = kModelDefaultGuidance;  // the model's 3
    EXPECT_TRUE(s->SetSampling(on).ok());
    EXPECT_EQ(s->guidance(), 3.0f);
    std::vector<float> rest(audio.begin() + part, audio.end());
    return RunStream(*s, rest, {rest.size()});
  };
  const std::vector<PoseFrame> a = switched(true), b = switched(false);
  ExpectSameFrames(a, b, 0.0f);
  // And the guided continuation differs from an unguided one.
  SessionOptions opt = Opts(6);
  auto u = MakeSession(model, opt);
  const size_t part = audio.size() / 2;
  ASSERT_TRUE(u->PushAudio(absl::MakeConstSpan(audio.data(), part)).ok());
  DrainSteps(*u);
  ASSERT_TRUE(u->SetStyle({{"waltz", 1.0f}}).ok());
  SamplingOptions off = opt.sampling;
  off.guidance = 1.0f;
  ASSERT_TRUE(u->SetSampling(off).ok());
  std::vector<float> rest(audio.begin() + part, audio.end());
  const std::vector<PoseFrame> unguided = RunStream(*u, rest, {rest.size()});
  ASSERT_EQ(unguided.size(), a.size());
  EXPECT_GT(CodesDiffer(a, unguided, 0), 0);
}

TEST(WarpedSession, PeriodLockDefaultSnapshotAndChanges) {
  testing::TinyModelOptions o;
  o.tempo_reference_bpm = 105.0;
  o.style_reference_bpm = {{"waltz", 90.0}};
  o.dance_period_beats = {{"waltz", 3.0}};
  auto no_default = LoadTinyModel(o);
  o.period_lock = 6.0;
  auto model = LoadTinyModel(o);
  EXPECT_EQ(no_default->default_period_lock(), 0.0f);
  EXPECT_EQ(model->default_period_lock(), 6.0f);
  const std::vector<float> audio = testing::ClickAudio(8.0, 110.0);
  auto run = [&](std::shared_ptr<const Model> m, float lock) {
    SamplingOptions sampling = Sampling(1.0f);
    sampling.period_lock = lock;
    SessionOptions opt = Opts(9, sampling);
    opt.style = {{"waltz", 1.0f}};
    auto s = MakeSession(std::move(m), opt);
    return std::make_pair(s->period_lock(), RunStream(*s, audio, {3000}));
  };
  // Negative = the model's default; an explicit weight overrides it.
  const auto [lock_default, by_default] = run(model, kModelDefaultPeriodLock);
  EXPECT_EQ(lock_default, 6.0f);
  ExpectSameFrames(by_default, run(no_default, 6.0f).second);
  const std::vector<PoseFrame> off = run(model, 0.0f).second;
  ExpectSameFrames(off, run(no_default, kModelDefaultPeriodLock).second);
  ASSERT_EQ(off.size(), by_default.size());
  EXPECT_GT(CodesDiffer(off, by_default, 0), static_cast<int>(off.size()) / 3);  // the lock changes the dance
  // A snapshot carries the code history: restored, a locked session continues exactly.
  SessionOptions opt = Opts(9, Sampling(1.0f));
  opt.style = {{"waltz", 1.0f}};
  auto s = MakeSession(model, opt);
  const size_t part = audio.size() / 2 + 77;
  ASSERT_TRUE(s->PushAudio(absl::MakeConstSpan(audio.data(), part)).ok());
  DrainSteps(*s);
  absl::StatusOr<SessionSnapshot> snap = s->Snapshot();
  ASSERT_TRUE(snap.ok());
  ASSERT_GE(snap->sampling.code_history.size(), 15u);
  EXPECT_EQ(snap->sampling.heading_history.size(), snap->sampling.code_history.size());
  std::vector<float> rest(audio.begin() + part, audio.end());
  const std::vector<PoseFrame> first = RunStream(*s, rest, {1000});
  auto fresh = MakeSession(model, opt);
  ASSERT_TRUE(fresh->Restore(*snap).ok());
  ExpectSameFrames(first, RunStream(*fresh, rest, {2500}));
  // Switched off mid-stream, and bad weights refused.
  SamplingOptions unlocked = Sampling(1.0f);
  unlocked.period_lock = 0.0f;
  ASSERT_TRUE(fresh->SetSampling(unlocked).ok());
  EXPECT_EQ(fresh->period_lock(), 0.0f);
  unlocked.period_lock = 101.0f;
  EXPECT_FALSE(fresh->SetSampling(unlocked).ok());
  unlocked.period_lock = std::nanf("");
  EXPECT_FALSE(fresh->SetSampling(unlocked).ok());
}

TEST(WarpedSession, PerStylePeriodLockFollowsTheTopStyle) {
  // time_base.style_period_lock {"waltz": 0} with period_lock 6: a waltz session is unlocked, a tango or
  // "none" session locked at 6, a mix takes its top style's, and SetStyle and Restore switch it.
  testing::TinyModelOptions o;
  o.tempo_reference_bpm = 105.0;
  o.style_reference_bpm = {{"waltz", 90.0}, {"tango", 120.0}};
  o.dance_period_beats = {{"waltz", 3.0}, {"tango", 2.0}};
  o.period_lock = 6.0;
  auto uniform = LoadTinyModel(o);
  o.style_period_lock = {{"waltz", 0.0}};
  auto model = LoadTinyModel(o);
  EXPECT_EQ(model->StylePeriodLock(0), 0.0f);  // waltz
  EXPECT_EQ(model->StylePeriodLock(1), 6.0f);  // tango: not named, the default
  EXPECT_EQ(model->StylePeriodLock(2), 6.0f);  // "none"
  EXPECT_EQ(uniform->StylePeriodLock(0), 6.0f);
  const std::vector<float> audio = testing::ClickAudio(8.0, 110.0);
  auto session = [&](std::shared_ptr<const Model> m, std::vector<std::pair<std::string, float>> style, float lock) {
    SamplingOptions sampling = Sampling(1.0f);
    sampling.period_lock = lock;
    SessionOptions opt = Opts(9, sampling);
    opt.style = std::move(style);
    return MakeSession(std::move(m), opt);
  };
  auto waltz = session(model, {{"waltz", 1.0f}}, kModelDefaultPeriodLock);
  EXPECT_EQ(waltz->period_lock(), 0.0f);
  EXPECT_EQ(session(model, {{"tango", 1.0f}}, kModelDefaultPeriodLock)->period_lock(), 6.0f);
  EXPECT_EQ(session(model, {}, kModelDefaultPeriodLock)->period_lock(), 6.0f);
  EXPECT_EQ(session(model, {{"waltz", 0.3f}, {"tango", 0.7f}}, kModelDefaultPeriodLock)->period_lock(), 6.0f);
  EXPECT_EQ(session(model, {{"waltz", 0.7f}, {"tango", 0.3f}}, kModelDefaultPeriodLock)->period_lock(), 0.0f);
  // A style named twice counts with its summed weight: waltz 0.3 + 0.3 outweighs tango 0.4.
  EXPECT_EQ(session(model, {{"waltz", 0.3f}, {"tango", 0.4f}, {"waltz", 0.3f}}, kModelDefaultPeriodLock)->period_lock(),
            0.0f);
  EXPECT_EQ(session(model, {{"tango", 0.5f}, {"waltz", 0.5f}}, kModelDefaultPeriodLock)->period_lock(), 6.0f);
  EXPECT_EQ(session(model, {{"waltz", 1.0f}}, 4.0f)->period_lock(), 4.0f);  // an explicit weight wins
  // The waltz dances exactly as an explicitly unlocked waltz of the uniform model, which differs from its
  // locked waltz (so the comparison could fail).
  const std::vector<PoseFrame> by_style = RunStream(*waltz, audio, {3000});
  ExpectSameFrames(by_style, RunStream(*session(uniform, {{"waltz", 1.0f}}, 0.0f), audio, {3000}));
  const std::vector<PoseFrame> locked = RunStream(*session(uniform, {{"waltz", 1.0f}}, kModelDefaultPeriodLock),
                                                  audio, {3000});
  ASSERT_EQ(locked.size(), by_style.size());
  EXPECT_GT(CodesDiffer(locked, by_style, 0), static_cast<int>(locked.size()) / 3);
  // SetStyle switches the default; a snapshot carries it into a session opened with another style.
  auto s = session(model, {{"tango", 1.0f}}, kModelDefaultPeriodLock);
  ASSERT_TRUE(s->SetStyle({{"waltz", 1.0f}}).ok());
  EXPECT_EQ(s->period_lock(), 0.0f);
  absl::StatusOr<SessionSnapshot> snap = s->Snapshot();
  ASSERT_TRUE(snap.ok());
  auto restored = session(model, {{"tango", 1.0f}}, kModelDefaultPeriodLock);
  ASSERT_TRUE(restored->Restore(*snap).ok());
  EXPECT_EQ(restored->period_lock(), 0.0f);
  ASSERT_TRUE(restored->SetStyle({{"tango", 1.0f}}).ok());
  EXPECT_EQ(restored->period_lock(), 6.0f);
}

TEST(WarpedSession, PeriodLockSharpnessFromTheModel) {
  // time_base.period_lock_sharpness: absent = 20; an explicit 20 dances exactly as absent; a softer kernel
  // (5: the lock also pulls toward the target's neighbours in the codebook) dances differently.
  testing::TinyModelOptions o;
  o.tempo_reference_bpm = 105.0;
  o.style_reference_bpm = {{"waltz", 90.0}};
  o.dance_period_beats = {{"waltz", 3.0}};
  o.period_lock = 6.0;
  auto absent = LoadTinyModel(o);
  o.period_lock_sharpness = 20.0;
  auto explicit20 = LoadTinyModel(o);
  o.period_lock_sharpness = 5.0;
  auto soft = LoadTinyModel(o);
  EXPECT_EQ(absent->period_lock_sharpness(), kDefaultPeriodLockSharpness);
  EXPECT_EQ(kDefaultPeriodLockSharpness, 20.0f);
  EXPECT_EQ(soft->period_lock_sharpness(), 5.0f);
  const std::vector<float> audio = testing::ClickAudio(8.0, 110.0);
  auto run = [&](std::shared_ptr<const Model> m) {
    SessionOptions opt = Opts(9, Sampling(1.0f));
    opt.style = {{"waltz", 1.0f}};
    auto s = MakeSession(std::move(m), opt);
    return RunStream(*s, audio, {3000});
  };
  const std::vector<PoseFrame> base = run(absent);
  ExpectSameFrames(base, run(explicit20));
  const std::vector<PoseFrame> softer = run(soft);
  ASSERT_EQ(softer.size(), base.size());
  EXPECT_GT(CodesDiffer(base, softer, 0), 0);
}

TEST(WarpedSession, RefusesABadTimeBase) {
  // Reference tempo outside 30..300 BPM is refused when the model loads.
  testing::TinyModelOptions o;
  o.tempo_reference_bpm = 5000.0;
  const std::string path = ::testing::TempDir() + "/bad_time_base.dncw";
  ASSERT_TRUE(testing::TinyModelWriter(o).WriteFile(path).ok());
  absl::StatusOr<std::shared_ptr<const Model>> m = LoadModel(path);
  ASSERT_FALSE(m.ok());
  EXPECT_TRUE(absl::StrContains(m.status().message(), "reference_bpm")) << m.status();
  o.tempo_reference_bpm = 105.0;
  o.style_reference_bpm = {{"salsa", 90.0}};  // not a style of this model
  ASSERT_TRUE(testing::TinyModelWriter(o).WriteFile(path).ok());
  m = LoadModel(path);
  ASSERT_FALSE(m.ok());
  EXPECT_TRUE(absl::StrContains(m.status().message(), "unknown style 'salsa'")) << m.status();
  // Bar clock: beats per bar outside 1..16, or a style the model does not have.
  o.style_reference_bpm = {};
  for (const auto& [beats, style, style_beats, message] :
       std::vector<std::tuple<int, std::string, int, std::string>>{
           {17, "", 0, "bar_clock.beats_per_bar"},
           {-1, "", 0, "bar_clock.beats_per_bar"},
           {4, "waltz", 0, "style_beats_per_bar['waltz'] must be in 1..16"},
           {4, "salsa", 3, "unknown style 'salsa'"}}) {
    o.bar_clock_beats = beats;
    o.style_beats_per_bar.clear();
    if (!style.empty()) o.style_beats_per_bar = {{style, style_beats}};
    ASSERT_TRUE(testing::TinyModelWriter(o).WriteFile(path).ok());
    m = LoadModel(path);
    ASSERT_FALSE(m.ok()) << beats << " " << style;
    EXPECT_TRUE(absl::StrContains(m.status().message(), message)) << m.status();
  }
  // Dance periods: outside 0.5..16 beats or an unknown style; a default lock without periods or out of range.
  o.bar_clock_beats = 0;
  o.style_beats_per_bar.clear();
  for (const auto& [style, beats, lock, message] :
       std::vector<std::tuple<std::string, double, double, std::string>>{
           {"waltz", 0.25, -1.0, "dance_period_beats['waltz'] must be in 0.5..16"},
           {"waltz", 17.0, -1.0, "dance_period_beats['waltz'] must be in 0.5..16"},
           {"salsa", 2.0, -1.0, "dance_period_beats names unknown style 'salsa'"},
           {"", 0.0, 5.0, "period_lock needs dance_period_beats"},
           {"waltz", 3.0, 101.0, "period_lock must be a number in 0..100"}}) {
    o.dance_period_beats.clear();
    if (!style.empty()) o.dance_period_beats = {{style, beats}};
    o.period_lock = lock;
    ASSERT_TRUE(testing::TinyModelWriter(o).WriteFile(path).ok());
    m = LoadModel(path);
    ASSERT_FALSE(m.ok()) << style << " " << beats << " " << lock;
    EXPECT_TRUE(absl::StrContains(m.status().message(), message)) << m.status();
  }
  // Per-style lock weights: in 0..100, known styles, and dance periods to lock to.
  o.dance_period_beats = {{"waltz", 3.0}};
  o.period_lock = -1.0;
  for (const auto& [style, lock, periods, message] :
       std::vector<std::tuple<std::string, double, bool, std::string>>{
           {"waltz", 101.0, true, "style_period_lock['waltz'] must be in 0..100"},
           {"waltz", -1.0, true, "style_period_lock['waltz'] must be in 0..100"},
           {"salsa", 4.0, true, "style_period_lock names unknown style 'salsa'"},
           {"waltz", 4.0, false, "style_period_lock needs dance_period_beats"}}) {
    o.style_period_lock = {{style, lock}};
    if (!periods) o.dance_period_beats.clear();
    ASSERT_TRUE(testing::TinyModelWriter(o).WriteFile(path).ok());
    m = LoadModel(path);
    ASSERT_FALSE(m.ok()) << style << " " << lock;
    EXPECT_TRUE(absl::StrContains(m.status().message(), message)) << m.status();
  }
  o.style_period_lock.clear();
  // Lock sharpness: a number in 1..100.
  o.dance_period_beats = {{"waltz", 3.0}};
  for (double sharpness : {0.5, 101.0, -3.0}) {
    o.period_lock_sharpness = sharpness;
    ASSERT_TRUE(testing::TinyModelWriter(o).WriteFile(path).ok());
    m = LoadModel(path);
    ASSERT_FALSE(m.ok()) << sharpness;
    EXPECT_TRUE(absl::StrContains(m.status().message(), "period_lock_sharpness must be a number in 1..100"))
        << m.status();
  }
  o.period_lock_sharpness = 0.0;
  // Period lock periods: integers in 1..4 per stream.
  o.dance_period_beats = {{"waltz", 3.0}};
  o.period_lock = 8.0;
  for (const auto& [upper, lower, message] : std::vector<std::tuple<int, int, std::string>>{
           {5, 0, "period_lock_periods['upper'] must be an integer in 1..4"},
           {1, -1, "period_lock_periods['lower'] must be an integer in 1..4"}}) {
    o.upper_lock_periods = upper;
    o.lower_lock_periods = lower;
    ASSERT_TRUE(testing::TinyModelWriter(o).WriteFile(path).ok());
    m = LoadModel(path);
    ASSERT_FALSE(m.ok()) << upper << " " << lower;
    EXPECT_TRUE(absl::StrContains(m.status().message(), message)) << m.status();
  }
}

}  // namespace
}  // namespace dance::engine
