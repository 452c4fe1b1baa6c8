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
  return c;
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
