#include "engine/runtime/internal/time_base.h"

#include <algorithm>
#include <cmath>
#include <tuple>

#include "engine/nn/status_macros.h"

namespace dance::engine {
namespace {

constexpr int kFeatureDims = audio::kNumFeatures;
constexpr int kPreDims = audio::kPreDims;
// Consumed feature frames are dropped only once this many have accumulated (amortised erase).
constexpr int64_t kForgetBatchFrames = 256;

}  // namespace

TimeBase::TimeBase(const Model& model, std::unique_ptr<audio::AudioFrontEnd> front_end)
    : model_(&model), reconstructor_(model.skeleton()), front_end_(std::move(front_end)) {}

absl::StatusOr<TimeBase> TimeBase::Create(const Model& model, int sample_rate, int channels) {
  audio::AudioFrontEndOptions options;
  options.sample_rate = sample_rate;
  options.channels = channels;
  DANCE_ASSIGN_OR_RETURN(std::unique_ptr<audio::AudioFrontEnd> front_end, audio::AudioFrontEnd::Create(options));
  TimeBase t(model, std::move(front_end));
  t.state_ = t.FreshState(ResolvedStyle());
  return t;
}

TimeBaseState TimeBase::FreshState(const ResolvedStyle& style) const {
  TimeBaseState s;
  WarpState& w = s.warp;
  w.clock = audio::TempoClock({.reference_bpm = warped() ? style.reference_bpm : 120.0});
  // The first decoded period is period 1; real frames start being emitted at the same index.
  w.first_pose = model_->config().frames_per_step;
  w.next_output = model_->config().frames_per_step;
  if (warped()) s.bar_frames = style.bar_frames;
  return s;
}

void TimeBase::SetStyle(const ResolvedStyle& style) {
  if (!warped()) return;
  if (style.reference_bpm != state_.warp.clock.options().reference_bpm) {
    state_.warp.clock.SetReference(style.reference_bpm);
  }
  if (model_->bar_clock()) state_.bar_frames = style.bar_frames;
}

absl::Status TimeBase::PushFloat(absl::Span<const float> interleaved, std::vector<PoseFrame>* out) {
  if (state_.ended) return absl::FailedPreconditionError("session: audio pushed after EndOfAudio");
  DANCE_RETURN_IF_ERROR(front_end_->PushFloat(interleaved));
  CollectFrames(out);
  return absl::OkStatus();
}

absl::Status TimeBase::PushInt16(absl::Span<const int16_t> interleaved, std::vector<PoseFrame>* out) {
  if (state_.ended) return absl::FailedPreconditionError("session: audio pushed after EndOfAudio");
  DANCE_RETURN_IF_ERROR(front_end_->PushInt16(interleaved));
  CollectFrames(out);
  return absl::OkStatus();
}

void TimeBase::End(std::vector<PoseFrame>* out) {
  if (state_.ended) return;
  TimeBaseState& s = state_;
  const SeqConfig& c = model_->config();
  // The dance covers every period the audio reaches into: count the 24 kHz samples received, round up to
  // whole periods, and feed silence so the front end completes them (the extra frames are not used).
  const int rate = front_end_->options().sample_rate;
  const int64_t in_frames = front_end_->input_frames();
  const int64_t samples24 = (in_frames * audio::kSampleRate + rate - 1) / rate;
  const int64_t period = static_cast<int64_t>(audio::kHopSamples) * c.frames_per_step;
  const int64_t periods = (samples24 + period - 1) / period;
  s.frames_limit = periods * c.frames_per_step;
  // Warped steps read past the last emitted real frame (the poses of real frame m come from warped
  // frames up to ceil(W_m) and the model reads one period of music behind them): pad extra real frames,
  // enough at the slowest clock rate (~0.65 warped frames per real frame).
  if (warped()) s.warp.output_limit = s.frames_limit;  // before the padding's frames reach EmitWarped
  const int64_t extra_frames = warped() ? 16 + 8 * (c.music_lookahead_steps + 1) * c.frames_per_step : 0;
  const int64_t missing24 = std::max<int64_t>(0, (s.frames_limit + extra_frames) * audio::kHopSamples - samples24);
  const int64_t pad = (missing24 + audio::kHopSamples) * rate / audio::kSampleRate + rate / 10 +
                      front_end_->BufferingSamples();
  std::vector<float> silence(static_cast<size_t>(pad) * front_end_->options().channels, 0.0f);
  front_end_->PushFloat(silence).IgnoreError();  // length is a multiple of the channel count
  front_end_->Flush().IgnoreError();
  CollectFrames(out);
  s.ended = true;
  if (warped()) {
    // Real frames [4, frames_limit) are emitted; the last one needs decoded warped frames up to
    // ceil(W), i.e. periods 1..K with 4 (K + 1) > ceil(W), and K steps read music up to 4 (K + s).
    const int64_t last = s.frames_limit - 1;
    if (last < s.warp.next_output) return;  // nothing more to emit
    const double w_last = s.warp.starts[last - s.warp.next_output];
    const int64_t needed_decoded = static_cast<int64_t>(std::ceil(w_last)) + 1;
    const int64_t periods_needed = (needed_decoded + c.frames_per_step - 1) / c.frames_per_step;  // K + 1
    s.warp.warped_limit = std::min<int64_t>(s.warp.clock.warped_frames(),
                                            (periods_needed - 1 + c.music_lookahead_steps) * c.frames_per_step);
    EmitWarped(out);
  }
}

void TimeBase::CollectFrames(std::vector<PoseFrame>* out) {
  front_end_->PopFrames(&popped_);
  const int64_t n = popped_.frames();
  if (n == 0) return;
  TimeBaseState& s = state_;
  s.beats_s.insert(s.beats_s.end(), popped_.beat_times_s.begin(), popped_.beat_times_s.end());
  s.pending_features.insert(s.pending_features.end(), popped_.features.begin(), popped_.features.end());
  s.pending_pre.insert(s.pending_pre.end(), popped_.pre.begin(), popped_.pre.end());
  if (warped()) {
    for (int64_t i = 0; i < n; ++i) {
      const audio::TempoClock::Span span = s.warp.clock.PushFeatures(popped_.features.data() + i * kFeatureDims);
      if (span.frame >= s.warp.next_output) s.warp.starts.push_back(span.begin);
      for (int64_t j = span.first_warped; j < span.end_warped; ++j) {
        s.warp.source.push_back(span.frame);
        s.warp.rate.push_back(span.rate);
      }
    }
  }
  s.frames_total += n;
  if (warped()) EmitWarped(out);
}

int TimeBase::StepsReady(int64_t steps_done) const {
  const SeqConfig& c = model_->config();
  const TimeBaseState& s = state_;
  int64_t usable;
  if (warped()) {
    usable = s.warp.clock.warped_frames();
    if (s.warp.warped_limit >= 0) usable = std::min(usable, s.warp.warped_limit);
  } else {
    usable = s.frames_limit >= 0 ? std::min(s.frames_total, s.frames_limit) : s.frames_total;
  }
  const int64_t total_steps = usable / c.frames_per_step - c.music_lookahead_steps;
  return static_cast<int>(std::max<int64_t>(0, total_steps - steps_done));
}

void TimeBase::Inputs(int64_t step, const float** music, const float** pre) {
  const int fps = model_->config().frames_per_step;
  const TimeBaseState& s = state_;
  if (warped()) {
    // Gather the token's warped frames from their source frames (docs/model.md section 8).
    const int64_t first_warped = (step + model_->config().music_lookahead_steps) * fps;
    music_token_.resize(static_cast<size_t>(fps) * kFeatureDims);
    int64_t src = 0;
    for (int f = 0; f < fps; ++f) {
      const int64_t w = first_warped + f - s.warp.first_source;
      src = s.warp.source[w] - s.first_pending_frame;
      audio::WarpedFeatureRow(s.pending_features.data() + src * kFeatureDims, s.warp.rate[w], first_warped + f,
                              model_->fold_tempo(), s.bar_frames,
                              music_token_.data() + static_cast<size_t>(f) * kFeatureDims);
    }
    *music = music_token_.data();
    *pre = s.pending_pre.data() + src * kPreDims;
    return;
  }
  const int64_t first = (step + model_->config().music_lookahead_steps) * fps - s.first_pending_frame;
  *music = s.pending_features.data() + first * kFeatureDims;
  *pre = s.pending_pre.data() + (first + fps - 1) * kPreDims;
}

void TimeBase::Forget(int64_t next_step) {
  const SeqConfig& c = model_->config();
  TimeBaseState& s = state_;
  const int64_t next_frame = (next_step + c.music_lookahead_steps) * c.frames_per_step;
  int64_t needed_from = next_frame;
  if (warped()) {
    // Forget warped sources no step will read again; the features follow their source frames.
    while (s.warp.first_source < next_frame && !s.warp.source.empty()) {
      s.warp.source.pop_front();
      s.warp.rate.pop_front();
      ++s.warp.first_source;
    }
    needed_from = s.warp.source.empty() ? s.frames_total : s.warp.source.front();
  }
  const int64_t drop = needed_from - s.first_pending_frame;
  if (drop >= kForgetBatchFrames) {
    s.pending_features.erase(s.pending_features.begin(), s.pending_features.begin() + drop * kFeatureDims);
    s.pending_pre.erase(s.pending_pre.begin(), s.pending_pre.begin() + drop * kPreDims);
    s.first_pending_frame += drop;
  }
}

std::array<Eigen::Vector3f, 24>& TimeBase::AddWarpedPose(std::pair<int, int> codes) {
  state_.warp.pose_codes.push_back(codes);
  return state_.warp.poses.emplace_back();
}

void TimeBase::EmitWarped(std::vector<PoseFrame>* out) {
  WarpState& warp = state_.warp;
  const int64_t decoded_end = warp.first_pose + static_cast<int64_t>(warp.poses.size());
  while (!warp.starts.empty() && (warp.output_limit < 0 || warp.next_output < warp.output_limit)) {
    // Warped position of real frame m, held at the first decoded pose (warped frame frames_per_step)
    // before the dance starts: w = max(W_m, frames_per_step + 1) (docs/model.md section 1). The pair
    // (a, a + 1) with a < w <= a + 1 keeps frame m causal: pose a + 1 comes from a step that read warped
    // music up to a < W_m, whose source frames are all < m. (The bound is the stream's first pose, not the
    // oldest pose kept: that one is the last frame's a, and a clock slower than one warped frame per real
    // frame puts two real frames in one interval (a, a + 1], the second of which was snapped to a + 1.)
    const double first_pose = static_cast<double>(model_->config().frames_per_step);
    const double w = std::max(warp.starts.front(), first_pose + 1.0);
    const int64_t a = static_cast<int64_t>(std::ceil(w)) - 1;
    if (a + 1 >= decoded_end) break;  // its poses are not decoded yet
    const float frac = static_cast<float>(w - static_cast<double>(a));
    const auto& pa = warp.poses[a - warp.first_pose];
    const auto& pb = warp.poses[a + 1 - warp.first_pose];
    PoseFrame& frame = out->emplace_back();
    frame.index = warp.next_output;
    frame.time_s = static_cast<double>(frame.index) / audio::kFrameRate;
    for (int j = 0; j < 24; ++j) frame.positions[j] = pa[j] + frac * (pb[j] - pa[j]);
    reconstructor_.ProjectBoneLengths(frame.positions);
    std::tie(frame.upper_code, frame.lower_code) = warp.pose_codes[a - warp.first_pose];
    warp.starts.pop_front();
    ++warp.next_output;
    // Poses before a are never needed again (W only grows).
    while (warp.first_pose < a) {
      warp.poses.pop_front();
      warp.pose_codes.pop_front();
      ++warp.first_pose;
    }
  }
}

void TimeBase::EmittedRealSpan(int64_t step, double* first, double* last, double* rate) const {
  const int fps = model_->config().frames_per_step;
  const int64_t j0 = (step + 1) * fps, j1 = j0 + fps - 1;
  *rate = 1.0;
  if (!warped()) {
    *first = static_cast<double>(j0);
    *last = static_cast<double>(j1);
    return;
  }
  const WarpState& w = state_.warp;
  // The last warped frame the step's music token read; the clock is known up to it whatever the chunking.
  const int64_t known = (step + model_->config().music_lookahead_steps + 1) * fps - 1;
  const int64_t i_known = known - w.first_source;
  if (w.source.empty() || i_known < 0 || i_known >= static_cast<int64_t>(w.source.size())) {
    *first = static_cast<double>(j0);  // (not reached: a ready step's token frames are in the clock)
    *last = static_cast<double>(j1);
    return;
  }
  *rate = std::max(w.rate[i_known], 0.1);
  auto real = [&](int64_t j) {
    const int64_t i = j - w.first_source;
    if (j <= known && i >= 0) return static_cast<double>(w.source[i]);
    return static_cast<double>(w.source[i_known]) + static_cast<double>(j - known) / *rate;
  };
  *first = real(j0);
  *last = real(j1);
}

TimeBaseSnapshot TimeBase::Snapshot() const { return {front_end_->Snapshot(), state_}; }

absl::Status TimeBase::Restore(const TimeBaseSnapshot& snapshot) {
  DANCE_RETURN_IF_ERROR(front_end_->Restore(snapshot.front_end));
  state_ = snapshot.state;
  return absl::OkStatus();
}

void TimeBase::TakeBeats(std::vector<double>* out) {
  out->insert(out->end(), state_.beats_s.begin(), state_.beats_s.end());
  state_.beats_s.clear();
}

void TimeBase::Reset(const ResolvedStyle& style) {
  front_end_->Reset();
  popped_.Clear();
  state_ = FreshState(style);
}

int64_t TimeBase::Bytes() const {
  const TimeBaseState& s = state_;
  int64_t n = static_cast<int64_t>(sizeof(audio::AudioFrontEnd) + sizeof(audio::FeatureExtractorState));
  n += static_cast<int64_t>((s.pending_features.capacity() + s.pending_pre.capacity()) * sizeof(float));
  n += static_cast<int64_t>(s.warp.source.size() * (sizeof(int64_t) + sizeof(double)) +
                            s.warp.starts.size() * sizeof(double) +
                            s.warp.poses.size() * (sizeof(s.warp.poses[0]) + sizeof(s.warp.pose_codes[0])) +
                            s.beats_s.capacity() * sizeof(double));
  return n;
}

}  // namespace dance::engine
