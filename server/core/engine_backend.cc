// LoadEngineBackend: the port (engine_port.h) implemented with the real engine, through its public header
// (engine/engine.h). The only file of the server that includes an engine header.
#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <optional>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"

#include "engine/engine.h"
#include "server/core/editor_port.h"
#include "server/core/engine_port.h"

namespace dance::server {
namespace {

engine::SamplingOptions ToEngine(const SamplingConfig& s) {
  engine::SamplingOptions o;
  o.temperature = s.temperature;
  o.top_k = s.top_k;
  o.top_p = s.top_p;
  o.guidance = s.guidance;
  o.period_lock = s.period_lock.value_or(-1.0f);  // unset in a StreamHeader: the model's default
  o.music_guidance = s.music_guidance.value_or(-1.0f);
  return o;
}

engine::MotionSource ToEngine(const MotionSpec& m, const char* name) {
  engine::MotionSource out;
  out.name = name;
  out.text = m.file;
  out.start_s = m.start_s;
  out.times_s = m.times_s;
  out.positions.resize(m.positions.size() / (kNumJoints * 3));
  for (size_t i = 0; i < out.positions.size(); ++i) {
    for (int j = 0; j < kNumJoints; ++j) {
      const float* p = &m.positions[(i * kNumJoints + j) * 3];
      out.positions[i][j] = Eigen::Vector3f(p[0], p[1], p[2]);
    }
  }
  return out;
}

engine::TrajectoryPoint ToEngine(const PathPointSpec& p) {
  engine::TrajectoryPoint q;
  q.t_s = p.t_s;
  q.x = p.x;
  q.z = p.z;
  q.facing = p.facing;
  return q;
}

FrameData ToFrameData(const engine::PoseFrame& f) {
  FrameData d;
  d.index = f.index;
  d.time_s = f.time_s;
  for (int j = 0; j < kNumJoints; ++j) {
    for (int k = 0; k < 3; ++k) d.positions[3 * j + k] = f.positions[j][k];
    const Eigen::Quaternionf& q = f.rotations[j];
    d.rotations[4 * j + 0] = q.w();
    d.rotations[4 * j + 1] = q.x();
    d.rotations[4 * j + 2] = q.y();
    d.rotations[4 * j + 3] = q.z();
  }
  d.upper_code = f.upper_code;
  d.lower_code = f.lower_code;
  return d;
}

// The spec as the engine's Controls; a seed starts no earlier than `seed_not_before_frame`; motion must
// start within `duration_s`. Errors are prefixed "controls: ".
absl::StatusOr<engine::Controls> BuildEngineControls(
    const ControlSpec& c, int64_t seed_not_before_frame,
    double duration_s = std::numeric_limits<double>::infinity()) {
  engine::ControlSpec spec;
  spec.seed = ToEngine(c.seed, "controls.seed");
  spec.given_upper = ToEngine(c.given_upper, "controls.given_upper");
  spec.given_lower = ToEngine(c.given_lower, "controls.given_lower");
  spec.keyframes = ToEngine(c.keyframes, "controls.keyframes");
  spec.inpaint = ToEngine(c.inpaint, "controls.inpaint");
  spec.mask_name = "controls.inpaint_known";
  for (const MaskSpanSpec& m : c.inpaint_known) spec.inpaint_known.push_back({m.start_s, m.end_s, m.joints});
  for (const PathPointSpec& p : c.trajectory) spec.trajectory.push_back(ToEngine(p));
  engine::BuildOptions options;
  options.seed_not_before_frame = seed_not_before_frame;
  options.duration_s = duration_s;
  return engine::BuildControls(spec, options);
}

// The frames [a, b) of `t` (a copy; empty if they do not overlap).
engine::MotionTrack CropTrack(const engine::MotionTrack& t, int64_t a, int64_t b) {
  engine::MotionTrack out;
  const int64_t from = std::max(a, t.first_frame), to = std::min(b, t.end_frame());
  if (from >= to) return out;
  out.first_frame = from;
  out.positions.assign(t.positions.begin() + (from - t.first_frame), t.positions.begin() + (to - t.first_frame));
  out.known.assign(t.known.begin() + (from - t.first_frame), t.known.begin() + (to - t.first_frame));
  return out;
}

// Live poses are kept this many frames behind the next step (the encoders' context), and at most this
// far ahead of it.
constexpr int64_t kLiveKeepBehind = 90;
constexpr int64_t kLiveMaxAhead = 30 * 30;
// While live poses come in, the rest of the motion controls is re-planned within this window around the
// next step (the whole of a long given motion is not re-encoded every step).
constexpr int64_t kBaseWindowBehind = 90, kBaseWindowAhead = 600;

class EngineSessionStream final : public EngineStream {
 public:
  explicit EngineSessionStream(std::unique_ptr<engine::Session> session, engine::Controls controls)
      : session_(std::move(session)), base_(std::move(controls)) {}

  absl::Status PushAudio(absl::Span<const float> interleaved) override { return session_->PushAudio(interleaved); }
  absl::Status PushAudioInt16(absl::Span<const int16_t> interleaved) override {
    return session_->PushAudioInt16(interleaved);
  }
  void EndOfAudio() override { session_->EndOfAudio(); }
  int StepsReady() const override { return session_->StepsReady(); }
  void PopFrames(std::vector<FrameData>* out) override {
    scratch_.clear();
    session_->PopFrames(&scratch_);
    for (const engine::PoseFrame& f : scratch_) out->push_back(ToFrameData(f));
    if (!scratch_.empty()) {
      last_root_ = scratch_.back().positions[0];
      have_root_ = true;
    }
  }
  void PopBeats(std::vector<double>* out) override { session_->PopBeats(out); }
  absl::Status SetStyle(const StyleMix& style) override { return session_->SetStyle(style); }
  absl::Status SetSampling(const SamplingConfig& sampling) override {
    engine::SamplingOptions o = ToEngine(sampling);
    // A Control whose sampling has no period_lock, guidance 0 or top_p 0 keeps the setting in effect ("unset
    // fields keep their value"): an explicit value stays, and so does "the model's default", which for the
    // period lock depends on the style (Model::StylePeriodLock) and must follow later style changes. In a
    // StreamHeader the same mean the model's defaults. A negative period_lock asks for the model's
    // style-following default back (engine: negative = Model::StylePeriodLock of the top style).
    const engine::SamplingOptions& now = session_->sampling();
    if (!sampling.period_lock.has_value()) o.period_lock = now.period_lock;
    if (!sampling.music_guidance.has_value()) o.music_guidance = now.music_guidance;
    if (o.guidance < 0.0f) o.guidance = now.guidance;
    if (o.top_p < 0.0f) o.top_p = now.top_p;
    o.foot_lock = now.foot_lock;  // a stream setting (StreamHeader.raw_feet), not the Control's
    return session_->SetSampling(o);
  }

  absl::Status SetControls(const ControlSpec& controls) override {
    absl::StatusOr<engine::Controls> c = BuildEngineControls(controls, NextFrame());
    if (!c.ok()) return c.status();
    base_ = *std::move(c);
    steer_path_.reset();
    dirty_ = true;
    return absl::OkStatus();
  }

  absl::Status Steer(const SteerTarget& target) override {
    const double now_s = static_cast<double>(NextFrame()) / 30.0;
    const Eigen::Vector3f root = have_root_ ? last_root_ : Eigen::Vector3f::Zero();
    std::vector<engine::TrajectoryPoint> path;
    if (target.kind == SteerTarget::Kind::kPoint) {
      if (!(target.t_s > now_s + 1.0 / 30.0)) {
        return absl::InvalidArgumentError(absl::StrCat("steer.point.t_ms ", target.t_s * 1000.0,
                                                       " is not after the next frame (", now_s * 1000.0, " ms)"));
      }
      path.push_back({now_s, root.x(), root.z(), std::nullopt});
      path.push_back({target.t_s, target.x, target.z, target.facing});
    } else if (target.x != 0.0f || target.z != 0.0f) {
      const float h = static_cast<float>(target.hold_s);
      path.push_back({now_s, root.x(), root.z(), target.facing});
      path.push_back({now_s + target.hold_s, root.x() + h * target.x, root.z() + h * target.z, target.facing});
    }  // else: a zero velocity releases the steering (no path)
    steer_path_ = std::move(path);
    dirty_ = true;
    return absl::OkStatus();
  }

  absl::Status PushPoses(absl::Span<const LivePose> poses) override {
    const int64_t next = NextFrame();
    absl::Status status;
    for (const LivePose& p : poses) {
      if (!live_.empty() && p.frame < live_.end_frame() - 1) {
        status.Update(absl::InvalidArgumentError(absl::StrCat("poses: time ", p.frame * 1000.0 / 30.0,
                                                              " ms is before the previous pose's")));
        continue;
      }
      if (p.frame > next + kLiveMaxAhead) {
        status.Update(absl::InvalidArgumentError(absl::StrCat(
            "poses: time ", p.frame * 1000.0 / 30.0, " ms is more than 30 s ahead of the dance (",
            next * 1000.0 / 30.0, " ms)")));
        continue;
      }
      if (live_.empty()) live_.first_frame = p.frame;
      // Frames between two poses are not given (the dance fills them); a second pose of a frame replaces it.
      while (live_.end_frame() <= p.frame) {
        live_.positions.emplace_back();
        live_.known.push_back(0);
      }
      engine::JointPositions& q = live_.positions.back();
      for (int j = 0; j < kNumJoints; ++j) q[j] = Eigen::Vector3f(p.positions[3 * j], p.positions[3 * j + 1], p.positions[3 * j + 2]);
      live_.known.back() = p.joints;
      live_active_ = true;
      dirty_ = true;
    }
    // Forget poses the encoders no longer need.
    const int64_t keep_from = next - kLiveKeepBehind;
    if (live_.first_frame < keep_from && !live_.empty()) {
      const int64_t drop = std::min<int64_t>(keep_from - live_.first_frame, static_cast<int64_t>(live_.positions.size()));
      live_.positions.erase(live_.positions.begin(), live_.positions.begin() + drop);
      live_.known.erase(live_.known.begin(), live_.known.begin() + drop);
      live_.first_frame += drop;
    }
    return status;
  }

  void EndPoses() override { live_active_ = false; }

  bool WaitsForPoses() const override {
    if (!live_active_) return false;
    double first = 0.0, last = 0.0;
    session_->NextStepRealFrames(&first, &last);
    const int64_t needed = static_cast<int64_t>(std::ceil(last)) + session_->ControlLookaheadFrames();
    return live_.end_frame() <= needed;
  }

  absl::Status CommitControls() override {
    if (!dirty_) return absl::OkStatus();
    dirty_ = false;
    engine::Controls c = base_;
    if (steer_path_.has_value()) c.trajectory = *steer_path_;
    if (!live_.empty()) {
      const int64_t next = NextFrame();
      c.motion = engine::CombineTracks(CropTrack(c.motion, next - kBaseWindowBehind, next + kBaseWindowAhead), live_);
    }
    return session_->SetControls(c);
  }

  engine::Session* session() { return session_.get(); }

 private:
  // The first real frame the next step emits.
  int64_t NextFrame() const {
    double first = 0.0, last = 0.0;
    session_->NextStepRealFrames(&first, &last);
    return std::max<int64_t>(0, static_cast<int64_t>(std::ceil(first)));
  }

  std::unique_ptr<engine::Session> session_;
  std::vector<engine::PoseFrame> scratch_;
  engine::Controls base_;                                       // from the header or the last Control
  std::optional<std::vector<engine::TrajectoryPoint>> steer_path_;  // set: replaces base_'s path
  engine::MotionTrack live_;                                    // live poses, the last few seconds
  bool live_active_ = false;                                    // poses are coming in
  bool dirty_ = false;                                          // the session's controls are behind
  Eigen::Vector3f last_root_ = Eigen::Vector3f::Zero();         // the pelvis of the last frame out
  bool have_root_ = false;
};

class EngineBackendImpl final : public EngineBackend {
 public:
  explicit EngineBackendImpl(std::shared_ptr<const engine::Model> model) : model_(std::move(model)) {
    desc_.model_id = model_->model_id();
    desc_.latency_ms = model_->LatencyMs();
    const engine::Skeleton& sk = model_->skeleton();
    desc_.joint_names = sk.joint_names;
    desc_.parents.assign(sk.parents.begin(), sk.parents.end());
    for (const Eigen::Vector3f& o : sk.offsets) desc_.rest_offsets.insert(desc_.rest_offsets.end(), {o.x(), o.y(), o.z()});
    desc_.styles = model_->styles();
    desc_.default_period_lock = model_->default_period_lock();
    for (size_t i = 0; i < desc_.styles.size(); ++i) {
      desc_.style_period_lock[desc_.styles[i]] = model_->StylePeriodLock(static_cast<int>(i));
    }
    desc_.default_guidance = model_->default_guidance();
    desc_.default_music_guidance = model_->default_music_guidance();
    desc_.default_top_p = model_->default_top_p();
    int lookahead = 0;
    for (const engine::VqEncoder* e : {model_->upper_encoder(), model_->lower_encoder()}) {
      if (e != nullptr) lookahead = std::max(lookahead, e->lookahead_frames());
    }
    desc_.pose_latency_ms = lookahead * 1000.0 / desc_.fps;
  }

  const ModelDescription& Describe() const override { return desc_; }

  absl::StatusOr<std::unique_ptr<EngineStream>> Open(const StreamConfig& config) const override {
    engine::SessionOptions o;
    o.input_sample_rate = config.sample_rate_hz;
    o.input_channels = config.channels;
    o.style = config.style;
    o.seed = config.seed;
    o.sampling = ToEngine(config.sampling);
    o.sampling.foot_lock = config.foot_lock;
    if (!config.controls.empty()) {
      absl::StatusOr<engine::Controls> c = BuildEngineControls(config.controls, 0);
      if (!c.ok()) return c.status();
      o.controls = *std::move(c);
    }
    absl::StatusOr<std::unique_ptr<engine::Session>> s = engine::Session::Create(model_, o);
    if (!s.ok()) return s.status();
    engine::Controls controls = o.controls;
    return std::make_unique<EngineSessionStream>(*std::move(s), std::move(controls));
  }

  absl::Status StepBatch(absl::Span<EngineStream* const> streams) const override {
    // Every stream was opened by this backend, so the downcast is an invariant, not a guess.
    thread_local std::vector<engine::Session*> sessions;
    sessions.clear();
    for (EngineStream* s : streams) sessions.push_back(static_cast<EngineSessionStream*>(s)->session());
    return engine::StepBatch(sessions);
  }

 private:
  std::shared_ptr<const engine::Model> model_;
  ModelDescription desc_;
};

}  // namespace

class EditorBackendImpl final : public EditorBackend {
 public:
  explicit EditorBackendImpl(std::shared_ptr<const engine::SgmdModel> model) : model_(std::move(model)) {
    const engine::SgmdConfig& c = model_->config();
    desc_.model_id = model_->model_id();
    desc_.styles = model_->styles();
    desc_.default_steps = model_->sampling_defaults().steps;
    desc_.default_guidance = model_->sampling_defaults().guidance;
    desc_.default_overlap_s = model_->sampling_defaults().overlap_frames / 30.0;
    desc_.window_s = c.frames / 30.0;
    const engine::Skeleton& sk = model_->skeleton();
    desc_.joint_names = sk.joint_names;
    for (int j = 0; j < kNumJoints; ++j) {
      desc_.parents.push_back(sk.parents[j]);
      for (int k = 0; k < 3; ++k) desc_.rest_offsets.push_back(sk.offsets[j][k]);
    }
  }

  const EditorDescription& Describe() const override { return desc_; }

  absl::StatusOr<EditOutput> Edit(const EditConfig& config, double max_audio_s,
                                  const std::function<bool(const EditProgress&)>& progress) const override {
    if (config.audio.empty()) return absl::InvalidArgumentError("audio: no song given");
    const std::string name = config.audio_name.empty() ? "audio" : config.audio_name;
    absl::StatusOr<engine::audio::DecodedAudio> audio = engine::audio::DecodeAudioMemory(
        absl::MakeConstSpan(reinterpret_cast<const uint8_t*>(config.audio.data()), config.audio.size()), name);
    if (!audio.ok()) return absl::InvalidArgumentError(absl::StrCat("audio: ", audio.status().message()));
    const double duration = audio->duration_s();
    if (duration > max_audio_s) {
      return absl::InvalidArgumentError(absl::StrCat("audio: ", duration, " s is longer than this server's limit of ",
                                                     max_audio_s, " s"));
    }
    engine::SgmdDanceOptions o;
    o.seed = config.seed;
    o.style = config.style;
    o.steps = config.steps;
    o.guidance = config.guidance;
    if (config.overlap_s > 0.0) o.overlap_frames = static_cast<int>(std::lround(config.overlap_s * 30.0));
    o.foot_lock = config.foot_lock;
    if (!config.controls.empty()) {
      absl::StatusOr<engine::Controls> c = BuildEngineControls(config.controls, 0, duration);
      if (!c.ok()) return c.status();
      o.controls = *std::move(c);
    }
    o.progress = [&progress](int64_t done, int64_t total) { return progress({done, total}); };
    absl::StatusOr<engine::audio::FeatureFrames> song = engine::SongFeatures(*audio);
    if (!song.ok()) return song.status();
    absl::StatusOr<engine::SgmdDance> dance = engine::GenerateSgmdDance(*model_, *song, o);
    if (dance.status().code() == absl::StatusCode::kNotFound) {  // an unknown style: the request's fault
      return absl::InvalidArgumentError(absl::StrCat("style: ", dance.status().message()));
    }
    if (!dance.ok()) return dance.status();
    EditOutput out;
    out.windows = dance->windows;
    out.steps = dance->steps;
    out.guidance = dance->guidance;
    out.overlap_s = dance->overlap_frames / 30.0;
    out.audio_s = duration;
    out.frames.reserve(dance->frames.size());
    for (const engine::PoseFrame& f : dance->frames) {
      if (f.time_s >= duration) break;
      out.frames.push_back(ToFrameData(f));
    }
    return out;
  }

 private:
  std::shared_ptr<const engine::SgmdModel> model_;
  EditorDescription desc_;
};

absl::StatusOr<std::unique_ptr<EditorBackend>> LoadEditorBackend(const std::string& model_path) {
  absl::StatusOr<std::shared_ptr<const engine::SgmdModel>> model = engine::SgmdModel::Load(model_path);
  if (!model.ok()) return model.status();
  return std::make_unique<EditorBackendImpl>(*std::move(model));
}

absl::StatusOr<std::unique_ptr<EngineBackend>> LoadEngineBackend(const std::string& model_path) {
  absl::StatusOr<std::shared_ptr<const engine::Model>> model = engine::LoadModel(model_path);
  if (!model.ok()) return model.status();
  if (engine::UpperMask() != kUpperJointBits || engine::LowerMask() != kLowerJointBits) {
    return absl::InternalError("server/core/engine_port.h's joint bits differ from the engine's body halves");
  }
  return std::make_unique<EngineBackendImpl>(*std::move(model));
}

}  // namespace dance::server
