// dance-generate: runs the streaming Session over an audio file (no server) and writes the dance.
//
//   dance-generate --audio FILE --out DANCE.json [--model M (default models/default.dncw)] [--seed S] [--style NAME[:W][,NAME:W...]]
//                  [--temperature T] [--top-k K] [--top-p P] [--guidance W] [--music-guidance M] [--period-lock B] [--chunk-samples N]
//                  [--crouch-guard 0|1] [--foot-lock 0|1] [--bvh DANCE.bvh] [--codes-out CODES.npy] [--quiet]
//                  [--seed-motion FILE] [--given-upper FILE] [--given-lower FILE] [--keyframes FILE]
//                  [--inpaint FILE --mask MASK.json] [--trajectory PATH.json]
//
// Controls (docs/controls.md): motion files are dance-motion/v1 JSON or BVH (SMPL joint names), placed on
// the audio timeline by their audio_offset_s; --keyframes needs a dance-motion/v1 file with "times_s";
// --trajectory reads dance-trajectory/v1, --mask dance-mask/v1. They combine (later ones win where two
// give the same joint: inpaint, given halves, seed, keyframes).
//
// --backend diffusion (or a --model of kind "sgmd") makes the dance with SGMD, the motion-diffusion editor
// (docs/diffusion.md; default model models/sgmd.dncw): the whole song at once in 5-s windows that agree on
// their overlaps, with the same control flags, --style, --seed and --foot-lock; --steps N (DDIM steps,
// default the model's), --guidance W (its classifier-free guidance on the music, 1 = off; default the
// model's), --overlap-s S (seconds two windows share; default the model's, 2.5). The token model's sampling
// flags (temperature, top-k/p, music guidance, period lock, crouch guard, codes/tokens out) do not apply.
//
// --gltf writes glTF 2.0 (a skinned skeleton with the dance as its animation; .glb binary or .gltf text),
// --vrma VRM Animation (client/export/gltf_writer.h).
//
// The audio is pushed in chunks of N input frames (default 4096; the dance does not depend on N), stepping
// whenever a step is ready, exactly as a live stream would. Frames past the end of the audio are dropped.
// Prints one JSON summary line (frames, seconds of audio, wall time, x real time) unless --quiet.
// --period-lock B: the period lock's weight (0 = off; default: the model's for the top style,
// time_base.style_period_lock or period_lock); the dance file records the weight in effect. --crouch-guard 0 turns the crouch guard off (default on; for
// measuring it, docs/model.md section 6). --foot-lock 0 turns the foot lock off (default on; docs/model.md
// section 7): the dance as decoded, planted feet not held. --music-guidance M: l_nm + M (l - l_nm), l_nm
// the model reading the music mean instead of the song's music stream (1 = off; default: the model's,
// sampling.music_guidance; docs/model.md section 6). --codes-out CODES.npy: the code of every step, as sampled
// (steps, 2) float32 (upper, lower), for comparing the engine's free-running draws with the PyTorch model's
// (training.eval.engine_parity); the dance file's per-frame codes are those of the warped frames shown, which
// can skip or repeat steps. --tokens-out TOKENS.npy (tempo-normalised models): every step's music token as
// the session read it, (steps, 4 x 108) float32 (the same comparison on the input side).
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "engine/audio/npy_writer.h"
#include "client/export/gltf_writer.h"
#include "engine/diffusion/sgmd_dance.h"
#include "engine/engine.h"
#include "engine/nn/weights_file.h"
#include "nlohmann/json.hpp"

namespace {

using namespace dance::engine;  // NOLINT: a tool's main

struct Flags {
  std::string audio, out, bvh, model, codes_out, tokens_out;
  std::string gltf, vrma;  // glTF 2.0 (.glb / .gltf) and VRM Animation outputs
  std::string backend;     // "", "tokens" or "diffusion"
  int diffusion_steps = 0;            // --steps (0: the model's)
  double overlap_s = -1.0;            // --overlap-s (negative: the model's)
  bool guidance_set = false;
  uint64_t seed = 0;
  std::string style;
  SamplingOptions sampling;
  std::string seed_motion, given_upper, given_lower, keyframes, inpaint, mask, trajectory;
  int64_t chunk_samples = 4096;
  bool quiet = false;
};

constexpr char kUsage[] =
    "usage: dance-generate --audio FILE --out DANCE.json [--model M] [--seed S] [--style NAME[:W],...]\n"
    "                      [--temperature T] [--top-k K] [--top-p P] [--guidance W] [--music-guidance M] [--period-lock B]\n"
    "                      [--chunk-samples N] [--crouch-guard 0|1] [--foot-lock 0|1]\n"
    "                      [--bvh DANCE.bvh] [--codes-out CODES.npy] [--tokens-out TOKENS.npy] [--quiet]\n"
    "                      [--seed-motion FILE] [--given-upper FILE] [--given-lower FILE] [--keyframes FILE]\n"
    "                      [--inpaint FILE --mask MASK.json] [--trajectory PATH.json]\n"
    "                      [--gltf DANCE.glb|.gltf] [--vrma DANCE.vrma]\n"
    "                      [--backend tokens|diffusion] [--steps N] [--overlap-s S]\n";

// The engine's beats within the song, rounded to the ms, for the file's "beat_times_s".
std::vector<double> BeatTimes(const std::vector<double>& beats, double duration_s) {
  std::vector<double> out;
  for (double t : beats) {
    if (t < duration_s) out.push_back(std::round(t * 1000.0) / 1000.0);
  }
  return out;
}

// The frames as plain arrays for the glTF / VRMA writers.
dance::client::MotionClip ClipOf(const Skeleton& skeleton, const std::vector<PoseFrame>& frames) {
  dance::client::MotionClip clip;
  clip.joint_names = skeleton.joint_names;
  for (int j = 0; j < kNumJoints; ++j) {
    clip.parents.push_back(skeleton.parents[j]);
    clip.rest_offsets.push_back({skeleton.offsets[j].x(), skeleton.offsets[j].y(), skeleton.offsets[j].z()});
  }
  for (const PoseFrame& f : frames) {
    clip.root_positions.push_back({f.positions[0].x(), f.positions[0].y(), f.positions[0].z()});
    for (const Eigen::Quaternionf& q : f.rotations) clip.rotations.push_back({q.w(), q.x(), q.y(), q.z()});
  }
  return clip;
}

absl::Status ParseFlags(int argc, char** argv, Flags* f) {
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--quiet") {
      f->quiet = true;
      continue;
    }
    if (arg == "--help" || arg == "-h") return absl::InvalidArgumentError("");
    if (i + 1 >= argc) return absl::InvalidArgumentError(absl::StrCat(arg, " needs a value"));
    const std::string v = argv[++i];
    bool ok = true;
    if (arg == "--audio") {
      f->audio = v;
    } else if (arg == "--out") {
      f->out = v;
    } else if (arg == "--bvh") {
      f->bvh = v;
    } else if (arg == "--gltf") {
      f->gltf = v;
    } else if (arg == "--vrma") {
      f->vrma = v;
    } else if (arg == "--codes-out") {
      f->codes_out = v;
    } else if (arg == "--tokens-out") {
      f->tokens_out = v;
    } else if (arg == "--model") {
      f->model = v;
    } else if (arg == "--style") {
      f->style = v;
    } else if (arg == "--seed-motion") {
      f->seed_motion = v;
    } else if (arg == "--given-upper") {
      f->given_upper = v;
    } else if (arg == "--given-lower") {
      f->given_lower = v;
    } else if (arg == "--keyframes") {
      f->keyframes = v;
    } else if (arg == "--inpaint") {
      f->inpaint = v;
    } else if (arg == "--mask") {
      f->mask = v;
    } else if (arg == "--trajectory") {
      f->trajectory = v;
    } else if (arg == "--seed") {
      ok = absl::SimpleAtoi(v, &f->seed);
    } else if (arg == "--temperature") {
      ok = absl::SimpleAtof(v, &f->sampling.temperature);
    } else if (arg == "--top-k") {
      ok = absl::SimpleAtoi(v, &f->sampling.top_k);
    } else if (arg == "--top-p") {
      ok = absl::SimpleAtof(v, &f->sampling.top_p);
    } else if (arg == "--guidance") {
      ok = absl::SimpleAtof(v, &f->sampling.guidance);
      f->guidance_set = true;
    } else if (arg == "--backend") {
      ok = v == "tokens" || v == "diffusion";
      f->backend = v;
    } else if (arg == "--steps") {
      ok = absl::SimpleAtoi(v, &f->diffusion_steps) && f->diffusion_steps >= 1;
    } else if (arg == "--overlap-s") {
      ok = absl::SimpleAtod(v, &f->overlap_s) && f->overlap_s >= 0.0 && std::isfinite(f->overlap_s);
    } else if (arg == "--music-guidance") {
      ok = absl::SimpleAtof(v, &f->sampling.music_guidance);
    } else if (arg == "--period-lock") {
      ok = absl::SimpleAtof(v, &f->sampling.period_lock);
    } else if (arg == "--crouch-guard") {
      ok = v == "0" || v == "1";
      f->sampling.crouch_guard = v == "1";
    } else if (arg == "--foot-lock") {
      ok = v == "0" || v == "1";
      f->sampling.foot_lock = v == "1";
    } else if (arg == "--chunk-samples") {
      ok = absl::SimpleAtoi(v, &f->chunk_samples) && f->chunk_samples >= 1;
    } else {
      return absl::InvalidArgumentError(absl::StrCat("unknown flag ", arg));
    }
    if (!ok) return absl::InvalidArgumentError(absl::StrCat("bad value for ", arg, ": '", v, "'"));
  }
  if (f->audio.empty() || f->out.empty()) return absl::InvalidArgumentError("--audio and --out are required");
  if (f->inpaint.empty() != f->mask.empty()) return absl::InvalidArgumentError("--inpaint and --mask go together");
  return absl::OkStatus();
}

// "waltz" or "waltz:0.7,tango:0.3" -> pairs.
absl::StatusOr<std::vector<std::pair<std::string, float>>> ParseStyle(const std::string& text) {
  std::vector<std::pair<std::string, float>> out;
  if (text.empty()) return out;
  for (absl::string_view part : absl::StrSplit(text, ',')) {
    std::vector<std::string> kv = absl::StrSplit(part, ':');
    float w = 1.0f;
    if (kv.size() > 2 || kv[0].empty() || (kv.size() == 2 && !absl::SimpleAtof(kv[1], &w))) {
      return absl::InvalidArgumentError(absl::StrCat("bad --style entry '", part, "' (want NAME or NAME:WEIGHT)"));
    }
    out.emplace_back(kv[0], w);
  }
  return out;
}

// The controls the flags name, combined into one Controls (`names` lists them for the dance file).
absl::StatusOr<Controls> BuildControlsFromFlags(const Flags& f, double duration_s, std::vector<std::string>* names) {
  ControlSpec spec;
  auto read = [](const std::string& path, MotionSource* m) -> absl::Status {
    if (path.empty()) return absl::OkStatus();
    absl::StatusOr<std::string> text = ReadTextFile(path);
    if (!text.ok()) return text.status();
    m->name = path;
    m->text = *std::move(text);
    return absl::OkStatus();
  };
  for (const auto& [path, m] : {std::pair{&f.inpaint, &spec.inpaint}, std::pair{&f.given_upper, &spec.given_upper},
                                std::pair{&f.given_lower, &spec.given_lower}, std::pair{&f.seed_motion, &spec.seed},
                                std::pair{&f.keyframes, &spec.keyframes}}) {
    if (absl::Status s = read(*path, m); !s.ok()) return s;
  }
  if (!f.mask.empty()) {
    // The mask's spans are checked against the dance when the controls are built.
    absl::StatusOr<std::string> text = ReadTextFile(f.mask);
    if (!text.ok()) return text.status();
    absl::StatusOr<std::vector<MaskSpan>> spans = ParseMaskSpansJson(*text, f.mask);
    if (!spans.ok()) return spans.status();
    spec.inpaint_known = *std::move(spans);
    spec.mask_name = f.mask;
  }
  if (!f.trajectory.empty()) {
    absl::StatusOr<std::vector<TrajectoryPoint>> path = ReadTrajectoryFile(f.trajectory);
    if (!path.ok()) return path.status();
    spec.trajectory = *std::move(path);
  }
  return BuildControls(spec, {.duration_s = duration_s}, names);
}

constexpr char kDefaultModel[] = "models/default.dncw";
constexpr char kFallbackModel[] = "models/test-tiny.dncw";  // until the trained model is committed
constexpr char kDefaultDiffusionModel[] = "models/sgmd.dncw";

// Whether the weights file at `path` is an SGMD model (metadata kind "sgmd").
bool IsSgmdFile(const std::string& path) {
  absl::StatusOr<WeightsFile> f = WeightsFile::Load(path);
  return f.ok() && f->metadata().value("kind", "") == "sgmd";
}

absl::Status RunDiffusion(const Flags& flags) {
  for (const auto& [set, name] : {std::pair{!flags.codes_out.empty(), "--codes-out"},
                                  std::pair{!flags.tokens_out.empty(), "--tokens-out"}}) {
    if (set) return absl::InvalidArgumentError(absl::StrCat(name, " needs the token model (--backend tokens)"));
  }
  const std::string path = flags.model.empty() ? kDefaultDiffusionModel : flags.model;
  absl::StatusOr<std::shared_ptr<const SgmdModel>> model = SgmdModel::Load(path);
  if (!model.ok()) return model.status();
  absl::StatusOr<audio::DecodedAudio> audio = audio::DecodeAudioFile(flags.audio);
  if (!audio.ok()) return audio.status();
  SgmdDanceOptions options;
  options.seed = flags.seed;
  absl::StatusOr<std::vector<std::pair<std::string, float>>> style = ParseStyle(flags.style);
  if (!style.ok()) return style.status();
  options.style = *style;
  options.steps = flags.diffusion_steps;
  if (flags.guidance_set) {
    if (!(flags.sampling.guidance > 0.0f)) {
      return absl::InvalidArgumentError(absl::StrCat("--guidance must be > 0, got ", flags.sampling.guidance));
    }
    options.guidance = flags.sampling.guidance;
  }
  if (flags.overlap_s >= 0.0) options.overlap_frames = static_cast<int>(std::lround(flags.overlap_s * 30.0));
  options.foot_lock = flags.sampling.foot_lock;
  std::vector<std::string> control_names;
  absl::StatusOr<Controls> controls = BuildControlsFromFlags(flags, audio->duration_s(), &control_names);
  if (!controls.ok()) return controls.status();
  options.controls = *std::move(controls);
  const auto start = std::chrono::steady_clock::now();
  absl::StatusOr<audio::FeatureFrames> song = SongFeatures(*audio);
  if (!song.ok()) return song.status();
  absl::StatusOr<SgmdDance> dance = GenerateSgmdDance(**model, *song, options);
  if (!dance.ok()) return dance.status();
  const double wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  const double duration = audio->duration_s();
  std::vector<PoseFrame>& frames = dance->frames;
  while (!frames.empty() && frames.back().time_s >= duration) frames.pop_back();
  DanceInfo info;
  info.model_id = (*model)->model_id();
  info.seed = flags.seed;
  nlohmann::json style_json = nlohmann::json::object();
  for (const auto& [name, w] : options.style) style_json[name] = w;
  info.extra = {{"backend", "diffusion"},
                {"style", style_json},
                {"steps", dance->steps},
                {"guidance", dance->guidance},
                {"overlap_s", dance->overlap_frames / 30.0},
                {"windows", dance->windows},
                {"repaired_frames", dance->repaired_frames},
                {"reanchored_seams", dance->reanchored_seams},
                {"foot_lock", options.foot_lock},
                {"audio_file", flags.audio},
                {"audio_duration_s", duration},
                {"beat_times_s", BeatTimes(song->beat_times_s, duration)},
                {"generator", "dance-generate"}};
  if (!control_names.empty()) info.extra["controls"] = control_names;
  const Skeleton& skeleton = (*model)->skeleton();
  if (absl::Status st = WriteDanceJson(flags.out, skeleton, frames, info); !st.ok()) return st;
  if (!flags.bvh.empty()) {
    if (absl::Status st = WriteBvh(flags.bvh, skeleton, frames); !st.ok()) return st;
  }
  for (const std::string& p : {flags.gltf, flags.vrma}) {
    if (p.empty()) continue;
    if (absl::Status st = dance::client::WriteMotionFile(p, ClipOf(skeleton, frames)); !st.ok()) return st;
  }
  if (!flags.quiet) {
    nlohmann::json summary = {{"frames", frames.size()}, {"windows", dance->windows}, {"repaired_frames", dance->repaired_frames},
                              {"reanchored_seams", dance->reanchored_seams}, {"steps", dance->steps},
                              {"audio_s", duration}, {"wall_s", wall_s},
                              {"x_real_time", wall_s > 0 ? duration / wall_s : 0.0},
                              {"model_id", (*model)->model_id()}, {"backend", "diffusion"}, {"out", flags.out}};
    std::cout << summary.dump() << std::endl;
  }
  return absl::OkStatus();
}

absl::Status Run(Flags flags) {
  if (flags.backend == "diffusion" || (flags.backend.empty() && !flags.model.empty() && IsSgmdFile(flags.model))) {
    return RunDiffusion(flags);
  }
  if (flags.diffusion_steps > 0 || flags.overlap_s >= 0.0) {
    return absl::InvalidArgumentError("--steps and --overlap-s are for the diffusion backend (--backend diffusion)");
  }
  if (flags.model.empty()) {
    flags.model = kDefaultModel;
    if (!std::filesystem::exists(flags.model) && std::filesystem::exists(kFallbackModel)) {
      std::cerr << "dance-generate: " << kDefaultModel << " not found; using " << kFallbackModel
                << " (random weights)\n";
      flags.model = kFallbackModel;
    }
  }
  absl::StatusOr<std::shared_ptr<const Model>> model = LoadModel(flags.model);
  if (!model.ok()) return model.status();
  absl::StatusOr<audio::DecodedAudio> audio = audio::DecodeAudioFile(flags.audio);
  if (!audio.ok()) return audio.status();
  SessionOptions options;
  options.input_sample_rate = audio->sample_rate;
  options.input_channels = audio->channels;
  options.seed = flags.seed;
  options.sampling = flags.sampling;
  absl::StatusOr<std::vector<std::pair<std::string, float>>> style = ParseStyle(flags.style);
  if (!style.ok()) return style.status();
  options.style = *style;
  std::vector<std::string> control_names;
  absl::StatusOr<Controls> controls = BuildControlsFromFlags(flags, audio->duration_s(), &control_names);
  if (!controls.ok()) return controls.status();
  options.controls = *std::move(controls);
  absl::StatusOr<std::unique_ptr<Session>> session = Session::Create(*model, options);
  if (!session.ok()) return session.status();
  Session& s = **session;

  const auto start = std::chrono::steady_clock::now();
  std::vector<float> codes;   // (steps, 2): every step's (upper, lower) code, for --codes-out
  std::vector<float> tokens;  // (steps, 4F): every step's music token (tempo-normalised models), --tokens-out
  auto step = [&]() -> absl::Status {
    if (absl::Status st = s.Step(); !st.ok()) return st;
    if (!flags.codes_out.empty()) {
      codes.push_back(static_cast<float>(s.last_codes().first));
      codes.push_back(static_cast<float>(s.last_codes().second));
    }
    if (!flags.tokens_out.empty()) {
      const std::vector<float>& t = s.last_warped_music_token();
      tokens.insert(tokens.end(), t.begin(), t.end());
    }
    return absl::OkStatus();
  };
  const size_t stride = static_cast<size_t>(flags.chunk_samples) * audio->channels;
  for (size_t pos = 0; pos < audio->samples.size(); pos += stride) {
    const size_t n = std::min(stride, audio->samples.size() - pos);
    if (absl::Status st = s.PushAudio(absl::MakeConstSpan(audio->samples.data() + pos, n)); !st.ok()) return st;
    while (s.StepsReady() > 0) {
      if (absl::Status st = step(); !st.ok()) return st;
    }
  }
  s.EndOfAudio();
  while (s.StepsReady() > 0) {
    if (absl::Status st = step(); !st.ok()) return st;
  }
  const double wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::vector<PoseFrame> frames;
  s.PopFrames(&frames);
  const double duration = audio->duration_s();
  while (!frames.empty() && frames.back().time_s >= duration) frames.pop_back();
  std::vector<double> beats;
  s.PopBeats(&beats);

  DanceInfo info;
  info.model_id = (*model)->model_id();
  info.seed = flags.seed;
  nlohmann::json style_json = nlohmann::json::object();
  for (const auto& [name, w] : options.style) style_json[name] = w;
  info.extra = {{"style", style_json},
                {"temperature", flags.sampling.temperature},
                {"top_k", flags.sampling.top_k},
                {"top_p", s.top_p()},
                {"guidance", s.guidance()},
                {"music_guidance", s.music_guidance()},
                {"period_lock", s.period_lock()},
                {"crouch_guard", flags.sampling.crouch_guard},
                {"foot_lock", flags.sampling.foot_lock},
                {"audio_file", flags.audio},
                {"audio_duration_s", duration},
                {"latency_ms", s.LatencyMs()},
                {"beat_times_s", BeatTimes(beats, duration)},
                {"generator", "dance-generate"}};
  if (!control_names.empty()) info.extra["controls"] = control_names;
  if (absl::Status st = WriteDanceJson(flags.out, (*model)->skeleton(), frames, info); !st.ok()) return st;
  if (!flags.bvh.empty()) {
    if (absl::Status st = WriteBvh(flags.bvh, (*model)->skeleton(), frames); !st.ok()) return st;
  }
  for (const std::string& path : {flags.gltf, flags.vrma}) {
    if (path.empty()) continue;
    if (absl::Status st = dance::client::WriteMotionFile(path, ClipOf((*model)->skeleton(), frames)); !st.ok()) {
      return st;
    }
  }
  if (!flags.codes_out.empty()) {
    const int64_t steps = static_cast<int64_t>(codes.size() / 2);
    if (absl::Status st = audio::WriteNpyFloat32(flags.codes_out, codes, steps, 2); !st.ok()) return st;
  }
  if (!flags.tokens_out.empty()) {
    const int64_t width = static_cast<int64_t>((*model)->config().frames_per_step) * audio::kNumFeatures;
    if (tokens.size() % width != 0 || tokens.empty()) {
      return absl::InvalidArgumentError("--tokens-out: the model is not tempo-normalised (no warped tokens)");
    }
    const int64_t steps = static_cast<int64_t>(tokens.size()) / width;
    if (absl::Status st = audio::WriteNpyFloat32(flags.tokens_out, tokens, steps, width); !st.ok()) return st;
  }
  if (!flags.quiet) {
    nlohmann::json summary = {{"frames", frames.size()},
                              {"steps", s.steps_done()},
                              {"audio_s", duration},
                              {"wall_s", wall_s},
                              {"x_real_time", wall_s > 0 ? duration / wall_s : 0.0},
                              {"model_id", (*model)->model_id()},
                              {"out", flags.out}};
    std::cout << summary.dump() << std::endl;
  }
  return absl::OkStatus();
}

}  // namespace

int main(int argc, char** argv) {
  Flags flags;
  if (absl::Status s = ParseFlags(argc, argv, &flags); !s.ok()) {
    if (!s.message().empty()) std::cerr << "dance-generate: " << s.message() << "\n";
    std::cerr << kUsage;
    return 2;
  }
  if (absl::Status s = Run(flags); !s.ok()) {
    std::cerr << "dance-generate: " << s << "\n";
    return 1;
  }
  return 0;
}
