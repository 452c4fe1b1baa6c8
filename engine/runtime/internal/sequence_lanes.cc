#include "engine/runtime/internal/sequence_lanes.h"

#include <algorithm>

#include "engine/audio/feature_layout.h"

namespace dance::engine {
namespace {

// `to` continues from `from`'s history (step, KV caches, Mamba states) with the style factors `style_bias`.
void StartLane(const SequenceState& from, const Eigen::MatrixXf& style_bias, SequenceState* to) {
  Eigen::MatrixXf bias = style_bias;  // may be to's own
  *to = from;
  to->style_bias = std::move(bias);
}

bool SameShapes(const SequenceState& a, const SequenceState& b) {
  return a.keys.size() == b.keys.size() && a.conv.size() == b.conv.size() &&
         (a.keys.empty() || a.keys[0].size() == b.keys[0].size());
}

}  // namespace

SequenceLanes::SequenceLanes(const Model& model) : model_(&model), state_(Fresh()) {}

LaneState SequenceLanes::Fresh() const {
  LaneState s;
  s.cond = model_->sequence().NewState();
  s.uncond = model_->sequence().NewState();
  s.upper_code = s.lower_code = model_->config().codebook_size;  // BOS
  return s;
}

void SequenceLanes::SetStyle(const ResolvedStyle& style) {
  // (Guidance is skipped while the style is "none": the conditional lane is then the unconditional one,
  // and Prepare starts the unconditional lane from it when a style comes.)
  const Eigen::VectorXf sv = model_->sequence().StyleVector(style.rows);
  model_->sequence().SetStyle(sv, &state_.cond);
  if (!state_.music_cond.keys.empty()) model_->sequence().SetStyle(sv, &state_.music_cond);
}

void SequenceLanes::Prepare(bool guidance, bool music_guidance) {
  LaneState& s = state_;
  const bool music_uncond = guidance && music_guidance;
  if (guidance && !s.uncond_live) StartLane(s.cond, s.uncond.style_bias, &s.uncond);
  // The "none" lane on the music mean continues the one that read the music mean if there was one (style
  // guidance switched on), else the "none" lane on the music (music guidance switched on).
  if (music_uncond && !s.music_uncond_live) {
    StartLane(s.music_cond_live ? s.music_cond : s.uncond, s.uncond.style_bias, &s.music_uncond);
  }
  if (music_guidance && !s.music_cond_live) StartLane(s.cond, s.cond.style_bias, &s.music_cond);
  s.uncond_live = guidance;
  s.music_cond_live = music_guidance;
  s.music_uncond_live = music_uncond;
}

const float* SequenceLanes::MeanMusicToken(const float* music) {
  const Eigen::VectorXf& mean = model_->sequence().music_mean();
  const auto& ranges = model_->music_guidance_features();
  if (ranges.empty()) return mean.data();
  mean_token_.assign(music, music + mean.size());
  for (int f = 0; f < model_->config().frames_per_step; ++f) {
    const int row = f * audio::kNumFeatures;
    for (const auto& [b, e] : ranges) {
      std::copy(mean.data() + row + b, mean.data() + row + e, mean_token_.begin() + row + b);
    }
  }
  return mean_token_.data();
}

void SequenceLanes::AddInputs(const float* music, const float* pre, std::vector<LaneInput>* inputs) {
  LaneState& s = state_;
  LaneInput in;
  in.music = music;
  in.pre = pre;
  in.upper_code = s.upper_code;
  in.lower_code = s.lower_code;
  in.state = &s.cond;
  inputs->push_back(in);
  if (s.uncond_live) {
    in.state = &s.uncond;
    inputs->push_back(in);
  }
  if (s.music_cond_live) {
    in.music = MeanMusicToken(music);
    in.state = &s.music_cond;
    inputs->push_back(in);
    if (s.music_uncond_live) {
      in.state = &s.music_uncond;
      inputs->push_back(in);
    }
  }
}

StepLogits SequenceLanes::Logits(const Workspace& workspace, int first) const {
  int next = first;
  auto take = [&](bool live) {
    LaneLogits g;
    if (!live) return g;
    g.u = workspace.logits_u.col(next).data();
    g.l = workspace.logits_l.col(next).data();
    ++next;
    return g;
  };
  StepLogits out;
  out.cond = take(true);
  out.uncond = take(state_.uncond_live);
  out.music_cond = take(state_.music_cond_live);
  out.music_uncond = take(state_.music_uncond_live);
  return out;
}

absl::Status SequenceLanes::Validate(const LaneState& s) const {
  const SequenceState fresh = model_->sequence().NewState();
  const absl::Status different = absl::InvalidArgumentError("session restore: snapshot is from a different model");
  if (!SameShapes(s.cond, fresh) || s.cond.style_bias.rows() != fresh.style_bias.rows() ||
      s.cond.style_bias.cols() != fresh.style_bias.cols()) {
    return different;
  }
  for (const SequenceState* lane : {&s.uncond, &s.music_cond, &s.music_uncond}) {
    if (!lane->keys.empty() && !SameShapes(*lane, fresh)) return different;
  }
  return absl::OkStatus();
}

void SequenceLanes::Restore(const LaneState& s) {
  state_ = s;
  state_.music_cond_live = s.music_cond_live && !s.music_cond.keys.empty();
  state_.music_uncond_live = s.music_uncond_live && !s.music_uncond.keys.empty();
}

void SequenceLanes::Reset(const ResolvedStyle& style) {
  state_ = Fresh();
  SetStyle(style);
}

int64_t SequenceLanes::Bytes(bool guidance) const {
  int64_t n = state_.cond.Bytes();
  if (guidance) n += state_.uncond.Bytes();
  if (!state_.music_cond.keys.empty()) n += state_.music_cond.Bytes();
  if (!state_.music_uncond.keys.empty()) n += state_.music_uncond.Bytes();
  return n;
}

}  // namespace dance::engine
