// LoadEngineBackend: the port (engine_port.h) implemented with the real engine, through its public header
// (engine/engine.h). The only file of the server that includes an engine header.
#include <memory>
#include <utility>
#include <vector>

#include "engine/engine.h"
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

class EngineSessionStream final : public EngineStream {
 public:
  explicit EngineSessionStream(std::unique_ptr<engine::Session> session) : session_(std::move(session)) {}

  absl::Status PushAudio(absl::Span<const float> interleaved) override { return session_->PushAudio(interleaved); }
  absl::Status PushAudioInt16(absl::Span<const int16_t> interleaved) override {
    return session_->PushAudioInt16(interleaved);
  }
  void EndOfAudio() override { session_->EndOfAudio(); }
  int StepsReady() const override { return session_->StepsReady(); }
  void PopFrames(std::vector<FrameData>* out) override {
    scratch_.clear();
    session_->PopFrames(&scratch_);
    for (const engine::PoseFrame& f : scratch_) {
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
      out->push_back(d);
    }
  }
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

  engine::Session* session() { return session_.get(); }

 private:
  std::unique_ptr<engine::Session> session_;
  std::vector<engine::PoseFrame> scratch_;
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
    absl::StatusOr<std::unique_ptr<engine::Session>> s = engine::Session::Create(model_, o);
    if (!s.ok()) return s.status();
    return std::make_unique<EngineSessionStream>(*std::move(s));
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

absl::StatusOr<std::unique_ptr<EngineBackend>> LoadEngineBackend(const std::string& model_path) {
  absl::StatusOr<std::shared_ptr<const engine::Model>> model = engine::LoadModel(model_path);
  if (!model.ok()) return model.status();
  return std::make_unique<EngineBackendImpl>(*std::move(model));
}

}  // namespace dance::server
