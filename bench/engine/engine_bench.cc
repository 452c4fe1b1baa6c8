// Engine benchmarks (they print numbers; nothing asserts a speed):
//   BM_Step/N        one code step of N sessions through StepBatch (sequence model + sampling + VQ decode +
//                    pose reconstruction); the "us_per_session" counter is the cost per session.
//   BM_StepWaltz/N/L the same with style waltz and the period lock off (L = 0) or at weight 8 (L = 1; the
//                    shipped model's weight for its other styles, its waltz being unlocked by default):
//                    what the lock's bias costs per step.
//   BM_ModelOnly/N   the sequence model's batched step alone.
//   BM_Generate      a whole stream (audio front end included) over 30 s of test audio: x real time.
//   BM_EndOfAudio/R  Session::EndOfAudio alone after 10 s of stereo audio at R Hz (the silence padding and
//                    front-end flush a session's end costs the thread that runs it).
//   BM_FootLock      the foot lock alone (FootLock::Apply) over 30 s of one session's decoded rumba frames
//                    (generated with the lock off), frame after frame: its cost per 30 fps frame; the
//                    "corrected" counter is the share of frames in which a foot's correction exceeds 5 mm,
//                    "shift_mm" the mean correction per foot and frame.
// The model is models/default.dncw when it exists (or $DANCE_BENCH_MODEL), otherwise a random model with
// the default training sizes built in memory. Memory per session is printed once at start.
//
//   build/bin/engine_bench --benchmark_filter=BM_Step
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>

#include "benchmark/benchmark.h"
#include "engine/runtime/session.h"
#include "tests/engine/runtime/testing/tiny_model.h"

namespace dance::engine {
namespace {

std::shared_ptr<const Model> BenchModel() {
  static std::shared_ptr<const Model> model = [] {
    const char* env = std::getenv("DANCE_BENCH_MODEL");
    const std::string path = env != nullptr ? env : "models/default.dncw";
    if (std::filesystem::exists(path)) {
      absl::StatusOr<std::shared_ptr<const Model>> m = LoadModel(path);
      if (m.ok()) {
        std::fprintf(stderr, "model: %s (%s)\n", path.c_str(), (*m)->model_id().c_str());
        return *m;
      }
      std::fprintf(stderr, "cannot load %s: %s\n", path.c_str(), std::string(m.status().message()).c_str());
    }
    std::fprintf(stderr, "model: random weights at the default training sizes\n");
    return testing::LoadTinyModel(testing::DefaultSizeOptions());
  }();
  return model;
}

// Sessions with enough audio queued for `steps` steps.
std::vector<std::unique_ptr<Session>> MakeSessions(int n, double seconds, const std::string& style = "",
                                                  float period_lock = kModelDefaultPeriodLock,
                                                  float guidance = kModelDefaultGuidance,
                                                  float music_guidance = kModelDefaultMusicGuidance) {
  const std::vector<float> audio = testing::TestAudio(seconds);
  std::vector<std::unique_ptr<Session>> out;
  for (int i = 0; i < n; ++i) {
    SessionOptions opt;
    opt.seed = static_cast<uint64_t>(i);
    if (!style.empty() && BenchModel()->StyleIndex(style).ok()) opt.style = {{style, 1.0f}};
    opt.sampling.period_lock = period_lock;
    opt.sampling.guidance = guidance;
    opt.sampling.music_guidance = music_guidance;
    out.push_back(*Session::Create(BenchModel(), opt));
    (void)out.back()->PushAudio(audio);
  }
  return out;
}

void StepSessions(benchmark::State& state, std::vector<std::unique_ptr<Session>> sessions) {
  const int n = static_cast<int>(sessions.size());
  std::vector<Session*> ptrs;
  for (auto& s : sessions) ptrs.push_back(s.get());
  std::vector<PoseFrame> sink;
  for (auto _ : state) {
    if (ptrs[0]->StepsReady() == 0) {
      state.PauseTiming();
      for (Session* s : ptrs) s->Reset();
      for (Session* s : ptrs) (void)s->PushAudio(testing::TestAudio(70.0));
      state.ResumeTiming();
    }
    (void)StepBatch(ptrs);
    for (Session* s : ptrs) {
      sink.clear();
      s->PopFrames(&sink);
    }
  }
  state.counters["us_per_session"] = benchmark::Counter(
      static_cast<double>(state.iterations()) * n, benchmark::Counter::kIsRate | benchmark::Counter::kInvert);
}
// The lock weight of the benchmarks that measure the lock (explicit: the shipped model's default for the
// waltz is 0 since default-20261204-2).
constexpr float kBenchLock = 8.0f;
void BM_Step(benchmark::State& state) { StepSessions(state, MakeSessions(static_cast<int>(state.range(0)), 70.0)); }
BENCHMARK(BM_Step)->Arg(1)->Arg(64)->Arg(256)->Unit(benchmark::kMicrosecond);

// Waltz sessions locked at weight 8 with style guidance off: one model pass per step. BM_StepWaltz/N/1 is
// the same with the model's guidance (the shipped model: 3, two passes; style "none" never needs two).
void BM_StepNoGuidance(benchmark::State& state) {
  StepSessions(state, MakeSessions(static_cast<int>(state.range(0)), 70.0, "waltz", kBenchLock, 1.0f));
}
BENCHMARK(BM_StepNoGuidance)->Arg(1)->Arg(64)->Unit(benchmark::kMicrosecond);

void BM_StepWaltz(benchmark::State& state) {
  StepSessions(state, MakeSessions(static_cast<int>(state.range(0)), 70.0, "waltz",
                                   state.range(1) == 0 ? 0.0f : kBenchLock));
}
BENCHMARK(BM_StepWaltz)->Args({1, 0})->Args({1, 1})->Args({64, 0})->Args({64, 1})->Unit(benchmark::kMicrosecond);

// BM_StepWaltz/N/1 with music guidance 0.5 on top of the model's style guidance: four model passes per step
// (style and "none", each on the song's music and on the music mean; docs/model.md section 6).
void BM_StepMusicGuidance(benchmark::State& state) {
  StepSessions(state, MakeSessions(static_cast<int>(state.range(0)), 70.0, "waltz", kBenchLock,
                                   kModelDefaultGuidance, 0.5f));
}
BENCHMARK(BM_StepMusicGuidance)->Arg(1)->Arg(64)->Unit(benchmark::kMicrosecond);

void BM_ModelOnly(benchmark::State& state) {
  const int n = static_cast<int>(state.range(0));
  const SequenceModel& seq = BenchModel()->sequence();
  std::vector<SequenceState> states(n, seq.NewState());
  std::vector<float> music(seq.config().music_dim(), 0.1f), pre(seq.config().pre_dim, 0.5f);
  std::vector<LaneInput> lanes(n);
  for (int i = 0; i < n; ++i) {
    lanes[i] = {music.data(), pre.data(), i % seq.config().codebook_size, 3, &states[i]};
  }
  Workspace ws;
  for (auto _ : state) {
    seq.Step(lanes, ws);
    benchmark::DoNotOptimize(ws.logits_u.data());
  }
  state.counters["us_per_session"] = benchmark::Counter(
      static_cast<double>(state.iterations()) * n, benchmark::Counter::kIsRate | benchmark::Counter::kInvert);
}
BENCHMARK(BM_ModelOnly)->Arg(1)->Arg(64)->Arg(256)->Unit(benchmark::kMicrosecond);

void BM_Generate(benchmark::State& state) {
  const double seconds = 30.0;
  const std::vector<float> audio = testing::TestAudio(seconds);
  for (auto _ : state) {
    SessionOptions opt;
    std::unique_ptr<Session> s = *Session::Create(BenchModel(), opt);
    for (size_t pos = 0; pos < audio.size(); pos += 4096) {
      (void)s->PushAudio(absl::MakeConstSpan(audio.data() + pos, std::min<size_t>(4096, audio.size() - pos)));
      while (s->StepsReady() > 0) (void)s->Step();
    }
    s->EndOfAudio();
    while (s->StepsReady() > 0) (void)s->Step();
    std::vector<PoseFrame> frames;
    s->PopFrames(&frames);
    benchmark::DoNotOptimize(frames.data());
  }
  state.counters["x_real_time"] = benchmark::Counter(seconds * static_cast<double>(state.iterations()),
                                                     benchmark::Counter::kIsRate);
}
BENCHMARK(BM_Generate)->Unit(benchmark::kMillisecond)->MinTime(2.0);

void BM_EndOfAudio(benchmark::State& state) {
  const int rate = static_cast<int>(state.range(0));
  std::vector<float> audio(static_cast<size_t>(rate) * 10 * 2);
  for (size_t i = 0; i < audio.size(); ++i) audio[i] = 0.3f * std::sin(0.01f * static_cast<float>(i / 2));
  for (auto _ : state) {
    state.PauseTiming();
    SessionOptions opt;
    opt.input_sample_rate = rate;
    opt.input_channels = 2;
    std::unique_ptr<Session> s = *Session::Create(BenchModel(), opt);
    (void)s->PushAudio(audio);
    state.ResumeTiming();
    s->EndOfAudio();
    benchmark::DoNotOptimize(s->StepsReady());
  }
}
BENCHMARK(BM_EndOfAudio)->Arg(24000)->Arg(44100)->Unit(benchmark::kMillisecond);

void BM_FootLock(benchmark::State& state) {
  SessionOptions opt;
  opt.seed = 1;
  opt.sampling.foot_lock = false;
  if (BenchModel()->StyleIndex("rumba").ok()) opt.style = {{"rumba", 1.0f}};
  std::unique_ptr<Session> s = *Session::Create(BenchModel(), opt);
  (void)s->PushAudio(testing::TestAudio(30.0));
  s->EndOfAudio();
  while (s->StepsReady() > 0) (void)StepBatch({s.get()});
  std::vector<PoseFrame> frames;
  s->PopFrames(&frames);
  const FootLock lock(BenchModel()->skeleton());
  FootLockState lock_state;
  size_t i = 0, corrected = 0, applied = 0;
  double shift = 0.0;
  for (auto _ : state) {
    if (i == frames.size()) {
      i = 0;
      lock_state = FootLockState();
    }
    std::array<Eigen::Vector3f, kNumJoints> p = frames[i].positions;
    lock.Apply(lock_state, &p);
    benchmark::DoNotOptimize(p);
    const float left = lock_state.feet[0].correction.norm(), right = lock_state.feet[1].correction.norm();
    corrected += left > 0.005f || right > 0.005f;
    shift += 0.5 * (left + right);
    ++applied;
    ++i;
  }
  state.counters["corrected"] = applied > 0 ? static_cast<double>(corrected) / static_cast<double>(applied) : 0.0;
  state.counters["shift_mm"] = applied > 0 ? 1000.0 * shift / static_cast<double>(applied) : 0.0;
  state.counters["frames"] = static_cast<double>(frames.size());
}
BENCHMARK(BM_FootLock)->Unit(benchmark::kNanosecond);

void PrintMemory() {
  // Waltz sessions with 1 s of audio, after one step (lanes are allocated or started at their first step):
  // no guidance (one lane), style guidance 2 (two), style guidance 2 and music guidance 0.5 (four).
  double kb[3];
  const float guidance[3] = {1.0f, 2.0f, 2.0f}, music[3] = {1.0f, 1.0f, 0.5f};
  for (int i = 0; i < 3; ++i) {
    std::vector<std::unique_ptr<Session>> s = MakeSessions(1, 1.0, "waltz", kModelDefaultPeriodLock, guidance[i], music[i]);
    (void)s[0]->Step();
    kb[i] = s[0]->StateBytes() / 1024.0;
  }
  std::fprintf(stderr, "memory per session: %.1f KB without guidance, %.1f KB with style guidance, %.1f KB with style "
               "and music guidance\n", kb[0], kb[1], kb[2]);
}

}  // namespace
}  // namespace dance::engine

int main(int argc, char** argv) {
  benchmark::Initialize(&argc, argv);
  dance::engine::PrintMemory();
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
