#include "engine/runtime/session.h"

#include <algorithm>
#include <tuple>

#include "absl/strings/str_cat.h"
#include "engine/nn/status_macros.h"

namespace dance::engine {

Session::Session(std::shared_ptr<const Model> model, const SessionOptions& options, TimeBase time,
                 MotionControl control)
    : model_(std::move(model)),
      options_(options),
      time_(std::move(time)),
      policy_(*model_, options.seed, options.sampling),
      lanes_(*model_),
      body_(*model_),
      control_(std::move(control)) {}

Session::~Session() = default;

absl::StatusOr<std::unique_ptr<Session>> Session::Create(std::shared_ptr<const Model> model,
                                                         const SessionOptions& options) {
  if (model == nullptr) return absl::InvalidArgumentError("session: no model");
  DANCE_RETURN_IF_ERROR(ValidateSamplingOptions(options.sampling));
  DANCE_ASSIGN_OR_RETURN(TimeBase time,
                         TimeBase::Create(*model, options.input_sample_rate, options.input_channels));
  DANCE_ASSIGN_OR_RETURN(MotionControl control, MotionControl::Create(*model, options.controls));
  std::unique_ptr<Session> s(new Session(std::move(model), options, std::move(time), std::move(control)));
  DANCE_RETURN_IF_ERROR(s->ApplyStyle(options.style));
  return s;
}

absl::Status Session::ApplyStyle(const StyleMix& style) {
  DANCE_ASSIGN_OR_RETURN(const ResolvedStyle resolved, ResolveStyle(*model_, style));
  lanes_.SetStyle(resolved);
  policy_.SetStyle(resolved);
  time_.SetStyle(resolved);
  return absl::OkStatus();
}

absl::Status Session::PushAudio(absl::Span<const float> interleaved) {
  const size_t first = output_.size();
  DANCE_RETURN_IF_ERROR(time_.PushFloat(interleaved, &output_));
  FinishFrames(first);
  return absl::OkStatus();
}

absl::Status Session::PushAudioInt16(absl::Span<const int16_t> interleaved) {
  const size_t first = output_.size();
  DANCE_RETURN_IF_ERROR(time_.PushInt16(interleaved, &output_));
  FinishFrames(first);
  return absl::OkStatus();
}

void Session::EndOfAudio() {
  const size_t first = output_.size();
  time_.End(&output_);
  FinishFrames(first);
}

void Session::FinishFrames(size_t first) {
  for (size_t i = first; i < output_.size(); ++i) {
    // The controls composite first; a frame whose lower body is given keeps its legs as given.
    const bool lower_given = control_.Composite(output_[i]);
    body_.Finish(output_[i], policy_.options().foot_lock && !lower_given);
  }
}

void Session::EmitFrames(const Eigen::Ref<const Eigen::MatrixXf>& up, const Eigen::Ref<const Eigen::MatrixXf>& low) {
  const SeqConfig& c = model_->config();
  // The model advanced the step: the step just taken is step() - 1, emitting period step().
  const int64_t step = lanes_.step();
  for (int f = 0; f < c.frames_per_step; ++f) policy_.ObserveDecodedHeight(low(kLowerHeightIndex, f));
  const size_t first = output_.size();
  if (time_.warped()) {
    for (int f = 0; f < c.frames_per_step; ++f) {
      body_.Reconstruct(up.col(f).data(), low.col(f).data(), &time_.AddWarpedPose(lanes_.codes()));
    }
    time_.EmitWarped(&output_);
  } else {
    const int64_t first_frame = step * c.frames_per_step;
    for (int f = 0; f < c.frames_per_step; ++f) {
      PoseFrame& frame = output_.emplace_back();
      frame.index = first_frame + f;
      frame.time_s = static_cast<double>(frame.index) / audio::kFrameRate;
      std::tie(frame.upper_code, frame.lower_code) = lanes_.codes();
      body_.Reconstruct(up.col(f).data(), low.col(f).data(), &frame.positions);
    }
  }
  FinishFrames(first);
  time_.Forget(step);
}

absl::Status Session::Step() {
  Session* self = this;
  return StepBatch(absl::MakeConstSpan(&self, 1));
}

void Session::PopFrames(std::vector<PoseFrame>* out) {
  out->insert(out->end(), output_.begin(), output_.end());
  output_.clear();
}

absl::StatusOr<SessionSnapshot> Session::Snapshot() const {
  SessionSnapshot s;
  s.input_sample_rate = options_.input_sample_rate;
  s.input_channels = options_.input_channels;
  s.time = time_.Snapshot();
  s.sampling = policy_.state();
  s.lanes = lanes_.state();
  s.body = body_.state();
  s.control = control_.state();
  s.output = output_;
  return s;
}

absl::Status Session::Restore(const SessionSnapshot& s) {
  if (s.input_sample_rate != options_.input_sample_rate || s.input_channels != options_.input_channels) {
    return absl::InvalidArgumentError("session restore: snapshot has a different input format");
  }
  // Every part validates before any changes, so a refused snapshot leaves the session as it was.
  DANCE_RETURN_IF_ERROR(lanes_.Validate(s.lanes));
  DANCE_RETURN_IF_ERROR(body_.Validate(s.body));
  DANCE_RETURN_IF_ERROR(policy_.Validate(s.sampling));
  DANCE_RETURN_IF_ERROR(control_.Validate(s.control));
  DANCE_RETURN_IF_ERROR(time_.Restore(s.time));
  lanes_.Restore(s.lanes);
  body_.Restore(s.body);
  policy_.Restore(s.sampling);
  control_.Restore(s.control);
  output_ = s.output;
  return absl::OkStatus();
}

void Session::Reset() {
  const absl::StatusOr<ResolvedStyle> style = ResolveStyle(*model_, options_.style);  // validated by Create
  time_.Reset(*style);
  policy_.Reset(options_.seed, options_.sampling, *style);
  lanes_.Reset(*style);
  body_.Reset();
  control_.Reset(control_.initial_plan());
  output_.clear();
}

int64_t Session::StateBytes() const {
  return static_cast<int64_t>(sizeof(*this)) + lanes_.Bytes(policy_.uses_guidance()) + body_.Bytes() +
         time_.Bytes() + policy_.Bytes();
}

void Session::NextStepRealFrames(double* first, double* last) const {
  double rate = 1.0;
  time_.EmittedRealSpan(lanes_.step(), first, last, &rate);
}

int Session::ControlLookaheadFrames() const {
  int frames = 0;
  for (const VqEncoder* e : {model_->upper_encoder(), model_->lower_encoder()}) {
    if (e != nullptr) frames = std::max(frames, e->lookahead_frames());
  }
  return frames;
}

absl::Status StepBatch(absl::Span<Session* const> sessions) {
  thread_local Workspace workspace;
  thread_local std::vector<LaneInput> lanes;
  thread_local std::vector<Session*> sorted;
  thread_local std::vector<int> first_lane;
  thread_local std::vector<Session*> group;
  thread_local std::vector<int> upper_codes, lower_codes;
  thread_local std::vector<VqDecoderState*> upper_states, lower_states;
  thread_local VqDecoderScratch upper_scratch, lower_scratch;
  sorted.assign(sessions.begin(), sessions.end());
  std::sort(sorted.begin(), sorted.end());
  if (std::adjacent_find(sorted.begin(), sorted.end()) != sorted.end()) {
    return absl::InvalidArgumentError("StepBatch: a session appears twice");
  }
  for (Session* s : sessions) {
    if (s == nullptr) return absl::InvalidArgumentError("StepBatch: null session");
    if (s->StepsReady() <= 0) {
      return absl::FailedPreconditionError(
          absl::StrCat("StepBatch: a session has no step ready (its audio for step ", s->steps_done(),
                       " has not arrived)"));
    }
  }
  // One pass per distinct model (normally exactly one).
  size_t done = 0;
  std::vector<bool> handled;  // only when several models share a batch (rare)
  while (done < sessions.size()) {
    const Model* model = nullptr;
    lanes.clear();
    first_lane.clear();
    for (size_t i = 0; i < sessions.size(); ++i) {
      Session* s = sessions[i];
      if (!handled.empty() && handled[i]) continue;
      if (model == nullptr) model = s->model_.get();
      if (s->model_.get() != model) {
        if (handled.empty()) handled.assign(sessions.size(), false);
        first_lane.push_back(-1);
        continue;
      }
      s->lanes_.Prepare(s->policy_.uses_guidance(), s->policy_.uses_music_guidance());
      const float* music = nullptr;
      const float* pre = nullptr;
      s->time_.Inputs(s->lanes_.step(), &music, &pre);
      first_lane.push_back(static_cast<int>(lanes.size()));
      s->lanes_.AddInputs(music, pre, &lanes);
    }
    model->sequence().Step(lanes, workspace);
    size_t slot = 0;
    for (size_t i = 0; i < sessions.size(); ++i) {
      if (!handled.empty() && handled[i]) continue;
      const int lane = first_lane[slot++];
      if (lane < 0) continue;
      Session* s = sessions[i];
      const StepLogits logits = s->lanes_.Logits(workspace, lane);
      StepControl control;
      if (s->control_.active()) {
        double first_real = 0.0, last_real = 0.0, rate = 1.0;
        s->time_.EmittedRealSpan(s->lanes_.step() - 1, &first_real, &last_real, &rate);
        control = s->control_.ForStep(first_real, last_real, s->body_.state().pose, rate, s->body_.state().lower,
                                      logits.cond.l);
      }
      const auto [upper, lower] = s->policy_.Sample(logits, s->body_.yaw(), s->control_.active() ? &control : nullptr);
      s->lanes_.SetCodes(upper, lower);
      group.push_back(s);
    }
    // Both VQ decoders over the whole group (one GEMM per conv), then per-session reconstruction.
    upper_codes.clear();
    lower_codes.clear();
    upper_states.clear();
    lower_states.clear();
    for (Session* s : group) {
      upper_codes.push_back(s->lanes_.codes().first);
      lower_codes.push_back(s->lanes_.codes().second);
      upper_states.push_back(s->body_.upper_state());
      lower_states.push_back(s->body_.lower_state());
    }
    const auto up = model->upper_decoder().DecodeBatch(upper_codes, upper_states, upper_scratch);
    const auto low = model->lower_decoder().DecodeBatch(lower_codes, lower_states, lower_scratch);
    const int fpc = model->config().frames_per_step;
    for (size_t g = 0; g < group.size(); ++g) {
      group[g]->EmitFrames(up.middleCols(g * fpc, fpc), low.middleCols(g * fpc, fpc));
    }
    for (size_t i = 0; i < sessions.size(); ++i) {
      if (!handled.empty() && sessions[i]->model_.get() == model) handled[i] = true;
    }
    done += group.size();
    group.clear();
  }
  return absl::OkStatus();
}

}  // namespace dance::engine
