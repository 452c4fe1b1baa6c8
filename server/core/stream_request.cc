#include "server/core/stream_request.h"

#include <algorithm>
#include <cmath>
#include <utility>

#include "absl/strings/str_cat.h"

namespace dance::server {

absl::StatusOr<StyleMix> ValidateStyle(const StyleMix& style, const ModelDescription& model) {
  StyleMix mix;
  for (const auto& [name, weight] : style) {
    if (std::find(model.styles.begin(), model.styles.end(), name) == model.styles.end() && name != "none") {
      return absl::InvalidArgumentError(absl::StrCat("unknown style '", name, "'"));
    }
    if (!(weight >= 0.0f) || !std::isfinite(weight)) {
      return absl::InvalidArgumentError(absl::StrCat("style '", name, "' has a bad weight"));
    }
    mix.emplace_back(name, weight);
  }
  if (mix.size() > 64) return absl::InvalidArgumentError("more than 64 styles");
  return mix;
}

absl::StatusOr<SamplingConfig> ValidateSampling(const SamplingRequest& s) {
  SamplingConfig c;
  if (!(s.temperature >= 0.0f) || s.temperature > 100.0f) {
    return absl::InvalidArgumentError("sampling.temperature must be in [0, 100]");
  }
  if (s.top_k < 0) return absl::InvalidArgumentError("sampling.top_k must be >= 0");
  if (!(s.top_p >= 0.0f && s.top_p <= 1.0f)) return absl::InvalidArgumentError("sampling.top_p must be in [0, 1]");
  if (!(s.guidance >= 0.0f) || s.guidance > 100.0f) {
    return absl::InvalidArgumentError("sampling.guidance must be in [0, 100]");
  }
  c.temperature = s.temperature;
  c.top_k = s.top_k;
  c.top_p = s.top_p == 0.0f ? -1.0f : s.top_p;           // 0: the model's default (negative)
  c.guidance = s.guidance == 0.0f ? -1.0f : s.guidance;  // 0: the model's default (negative)
  if (s.period_lock.has_value()) {
    const float lock = *s.period_lock;
    if (!(lock == -1.0f || (lock >= 0.0f && lock <= 100.0f))) {
      return absl::InvalidArgumentError("sampling.period_lock must be in [0, 100], or -1 for the model's default");
    }
    c.period_lock = lock;
  }
  if (s.music_guidance.has_value()) {
    const float m = *s.music_guidance;
    if (!(m == -1.0f || (m >= 0.0f && m <= 100.0f))) {
      return absl::InvalidArgumentError("sampling.music_guidance must be in [0, 100], or -1 for the model's default");
    }
    c.music_guidance = m;
  }
  return c;
}

absl::StatusOr<ValidatedStream> ValidateStream(const StreamRequest& r, const ModelDescription& model,
                                               const StreamLimits& limits) {
  ValidatedStream v;
  if (r.sample_rate_hz < limits.min_sample_rate_hz || r.sample_rate_hz > limits.max_sample_rate_hz) {
    return absl::InvalidArgumentError(absl::StrCat("sample_rate_hz ", r.sample_rate_hz, " outside [",
                                                   limits.min_sample_rate_hz, ", ", limits.max_sample_rate_hz,
                                                   "] Hz"));
  }
  if (r.channels < 1 || r.channels > limits.max_channels) {
    return absl::InvalidArgumentError(
        absl::StrCat("channels ", r.channels, " outside [1, ", limits.max_channels, "]"));
  }
  if (!r.format.has_value()) return absl::InvalidArgumentError("sample_format must be F32LE or S16LE");
  v.format = *r.format;
  if (r.client_name.size() > 64) return absl::InvalidArgumentError("client_name longer than 64 bytes");
  absl::StatusOr<StyleMix> style = ValidateStyle(r.style, model);
  if (!style.ok()) return style.status();
  v.config.style = *std::move(style);
  if (r.sampling.has_value()) {
    absl::StatusOr<SamplingConfig> s = ValidateSampling(*r.sampling);
    if (!s.ok()) return s.status();
    v.config.sampling = *s;
  }
  v.config.sample_rate_hz = r.sample_rate_hz;
  v.config.channels = r.channels;
  v.config.seed = r.seed;
  v.client_name = r.client_name;
  v.omit_rotations = r.omit_rotations;
  v.config.foot_lock = !r.raw_feet;
  if (absl::Status st = ValidateControlSpec(r.controls); !st.ok()) return st;
  v.config.controls = r.controls;
  return v;
}

absl::StatusOr<ValidatedControl> ValidateControl(const ControlRequest& r, const ModelDescription& model) {
  ValidatedControl c;
  if (!r.style.empty()) {
    absl::StatusOr<StyleMix> mix = ValidateStyle(r.style, model);
    if (!mix.ok()) return mix.status();
    c.style = *std::move(mix);
  }
  if (r.sampling.has_value()) {
    absl::StatusOr<SamplingConfig> s = ValidateSampling(*r.sampling);
    if (!s.ok()) return s.status();
    c.sampling = *s;
  }
  // Checked when the session applies them (ValidateControlSpec, ValidateSteer): a bad one is refused with
  // a warning, not by ending the stream.
  c.controls = r.controls;
  c.steer = r.steer;
  return c;
}

namespace {

bool FiniteTime(double t_s) { return std::isfinite(t_s) && t_s >= 0.0 && t_s <= 1e6; }

absl::Status ValidateMotion(const MotionSpec& m, const char* name) {
  if (!m.positions.empty() && !m.file.empty()) {
    return absl::InvalidArgumentError(absl::StrCat("controls.", name, ": give positions or a file, not both"));
  }
  if (m.positions.size() % (kNumJoints * 3) != 0) {
    return absl::InvalidArgumentError(absl::StrCat("controls.", name, ".positions: ", m.positions.size(),
                                                   " numbers are not whole poses of 24 joints x 3"));
  }
  const size_t frames = m.positions.size() / (kNumJoints * 3);
  if (frames > kMaxControlFrames) {
    return absl::InvalidArgumentError(absl::StrCat("controls.", name, ": ", frames, " poses, more than ",
                                                   kMaxControlFrames, " (send a longer motion as a file)"));
  }
  for (float v : m.positions) {
    if (!std::isfinite(v) || std::abs(v) > 100.0f) {
      return absl::InvalidArgumentError(
          absl::StrCat("controls.", name, ".positions: not a finite position within 100 m"));
    }
  }
  if (!std::isfinite(m.start_s) || std::abs(m.start_s) > 1e6) {
    return absl::InvalidArgumentError(absl::StrCat("controls.", name, ".start_ms is not a usable time"));
  }
  if (!m.times_s.empty()) {
    if (!m.file.empty() || m.times_s.size() != frames) {
      return absl::InvalidArgumentError(absl::StrCat("controls.", name, ".times_ms: one time per pose, ",
                                                     m.times_s.size(), " for ", frames));
    }
    for (double t : m.times_s) {
      if (!FiniteTime(t)) return absl::InvalidArgumentError(absl::StrCat("controls.", name, ".times_ms: bad time"));
    }
  }
  return absl::OkStatus();
}

}  // namespace

absl::Status ValidateControlSpec(const ControlSpec& c) {
  for (const auto& [m, name] : {std::pair{&c.seed, "seed"}, std::pair{&c.given_upper, "given_upper"},
                                std::pair{&c.given_lower, "given_lower"}, std::pair{&c.keyframes, "keyframes"},
                                std::pair{&c.inpaint, "inpaint"}}) {
    if (absl::Status s = ValidateMotion(*m, name); !s.ok()) return s;
  }
  if (c.inpaint_known.size() > 10000) return absl::InvalidArgumentError("controls.inpaint_known: too many spans");
  for (const MaskSpanSpec& span : c.inpaint_known) {
    if (!FiniteTime(span.start_s) || !FiniteTime(span.end_s) || !(span.start_s < span.end_s)) {
      return absl::InvalidArgumentError("controls.inpaint_known: a span needs start_ms < end_ms, both >= 0");
    }
    if (span.joints.empty() || span.joints.size() > 64) {
      return absl::InvalidArgumentError("controls.inpaint_known: a span lists 1 to 64 joints");
    }
  }
  if (c.trajectory.size() > kMaxControlFrames) {
    return absl::InvalidArgumentError("controls.trajectory: too many points");
  }
  for (size_t i = 0; i < c.trajectory.size(); ++i) {
    const PathPointSpec& p = c.trajectory[i];
    if (!FiniteTime(p.t_s) || !std::isfinite(p.x) || !std::isfinite(p.z) || std::abs(p.x) > 1000.0f ||
        std::abs(p.z) > 1000.0f || (p.facing.has_value() && !std::isfinite(*p.facing))) {
      return absl::InvalidArgumentError(absl::StrCat("controls.trajectory[", i, "]: not a finite point within 1 km"));
    }
    if (i > 0 && !(p.t_s > c.trajectory[i - 1].t_s)) {
      return absl::InvalidArgumentError(absl::StrCat("controls.trajectory[", i, "]: times must increase"));
    }
  }
  if (c.trajectory.size() == 1) return absl::InvalidArgumentError("controls.trajectory: a path needs >= 2 points");
  return absl::OkStatus();
}

absl::Status ValidateSteer(const SteerTarget& t) {
  if (!std::isfinite(t.x) || !std::isfinite(t.z) || (t.facing.has_value() && !std::isfinite(*t.facing))) {
    return absl::InvalidArgumentError("steer: coordinates must be finite");
  }
  if (t.kind == SteerTarget::Kind::kPoint) {
    if (!FiniteTime(t.t_s)) return absl::InvalidArgumentError("steer.point.t_ms must be a time >= 0");
    if (std::abs(t.x) > 1000.0f || std::abs(t.z) > 1000.0f) {
      return absl::InvalidArgumentError("steer.point: farther than 1 km");
    }
    return absl::OkStatus();
  }
  if (std::hypot(t.x, t.z) > 10.0f) return absl::InvalidArgumentError("steer.velocity: faster than 10 m/s");
  if (!(t.hold_s > 0.0 && t.hold_s <= 60.0)) {
    return absl::InvalidArgumentError("steer.velocity.hold_ms must be in (0, 60000]");
  }
  return absl::OkStatus();
}

absl::StatusOr<LivePose> ValidatePose(const PoseRequest& r) {
  LivePose p;
  switch (r.part) {
    case BodyPart::kUpper: p.joints = kUpperJointBits; break;
    case BodyPart::kLower: p.joints = kLowerJointBits; break;
    case BodyPart::kAll: p.joints = kAllJointBits; break;
    case BodyPart::kUnspecified: return absl::InvalidArgumentError("poses.part must be upper, lower or all");
  }
  if (r.positions.size() != kNumJoints * 3) {
    return absl::InvalidArgumentError(
        absl::StrCat("poses.positions: ", r.positions.size(), " numbers, expected 24 joints x 3 = 72"));
  }
  for (float v : r.positions) {
    if (!std::isfinite(v) || std::abs(v) > 100.0f) {
      return absl::InvalidArgumentError("poses.positions: not a finite position within 100 m");
    }
  }
  if (!std::isfinite(r.time_ms) || r.time_ms < 0.0 || r.time_ms > 1e9) {
    return absl::InvalidArgumentError("poses.time_ms must be a time in [0, 1e9] ms");
  }
  p.frame = std::llround(r.time_ms * 30.0 / 1000.0);
  std::copy(r.positions.begin(), r.positions.end(), p.positions.begin());
  return p;
}

absl::Status ValidateChunk(size_t pcm_bytes, const ValidatedStream& stream, const StreamLimits& limits) {
  const size_t frame_bytes = static_cast<size_t>(BytesPerSample(stream.format) * stream.config.channels);
  if (pcm_bytes % frame_bytes != 0) {
    return absl::InvalidArgumentError(
        absl::StrCat("audio chunk of ", pcm_bytes, " bytes is not a whole number of ", frame_bytes,
                     "-byte sample frames"));
  }
  if (pcm_bytes / frame_bytes > static_cast<size_t>(limits.max_chunk_samples)) {
    return absl::InvalidArgumentError(absl::StrCat("audio chunk of ", pcm_bytes / frame_bytes,
                                                   " sample frames exceeds the limit of ",
                                                   limits.max_chunk_samples));
  }
  return absl::OkStatus();
}

}  // namespace dance::server
