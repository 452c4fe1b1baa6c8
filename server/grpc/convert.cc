#include "server/grpc/convert.h"

#include <algorithm>
#include <cmath>

#include "absl/strings/str_cat.h"

namespace dance::server {
namespace {

using nlohmann::json;

}  // namespace

absl::StatusOr<StyleMix> StyleFromProto(const google::protobuf::RepeatedPtrField<dance::v1::StyleWeight>& style,
                                        const ModelDescription& model) {
  StyleMix mix;
  for (const dance::v1::StyleWeight& w : style) {
    if (std::find(model.styles.begin(), model.styles.end(), w.name()) == model.styles.end() &&
        w.name() != "none") {
      return absl::InvalidArgumentError(absl::StrCat("unknown style '", w.name(), "'"));
    }
    if (!(w.weight() >= 0.0f) || !std::isfinite(w.weight())) {
      return absl::InvalidArgumentError(absl::StrCat("style '", w.name(), "' has a bad weight"));
    }
    mix.emplace_back(w.name(), w.weight());
  }
  if (mix.size() > 64) return absl::InvalidArgumentError("more than 64 styles");
  return mix;
}

absl::StatusOr<SamplingConfig> SamplingFromProto(const dance::v1::Sampling& s) {
  SamplingConfig c;
  if (!(s.temperature() >= 0.0f) || s.temperature() > 100.0f) {
    return absl::InvalidArgumentError("sampling.temperature must be in [0, 100]");
  }
  if (s.top_k() < 0) return absl::InvalidArgumentError("sampling.top_k must be >= 0");
  if (!(s.top_p() >= 0.0f && s.top_p() <= 1.0f)) return absl::InvalidArgumentError("sampling.top_p must be in [0, 1]");
  if (!(s.guidance() >= 0.0f) || s.guidance() > 100.0f) {
    return absl::InvalidArgumentError("sampling.guidance must be in [0, 100]");
  }
  c.temperature = s.temperature();
  c.top_k = s.top_k();
  c.top_p = s.top_p() == 0.0f ? -1.0f : s.top_p();  // 0: the model's default (negative)
  c.guidance = s.guidance() == 0.0f ? -1.0f : s.guidance();  // 0: the model's default (negative)
  if (s.has_period_lock()) {
    const float lock = s.period_lock();
    if (!(lock == -1.0f || (lock >= 0.0f && lock <= 100.0f))) {
      return absl::InvalidArgumentError("sampling.period_lock must be in [0, 100], or -1 for the model's default");
    }
    c.period_lock = lock;
  }
  if (s.has_music_guidance()) {
    const float m = s.music_guidance();
    if (!(m == -1.0f || (m >= 0.0f && m <= 100.0f))) {
      return absl::InvalidArgumentError("sampling.music_guidance must be in [0, 100], or -1 for the model's default");
    }
    c.music_guidance = m;
  }
  return c;
}

absl::StatusOr<ValidatedHeader> ValidateHeader(const dance::v1::StreamHeader& h, const ModelDescription& model,
                                               const StreamLimits& limits) {
  ValidatedHeader v;
  if (h.sample_rate_hz() < limits.min_sample_rate_hz || h.sample_rate_hz() > limits.max_sample_rate_hz) {
    return absl::InvalidArgumentError(absl::StrCat("sample_rate_hz ", h.sample_rate_hz(), " outside [",
                                                   limits.min_sample_rate_hz, ", ", limits.max_sample_rate_hz,
                                                   "] Hz"));
  }
  if (h.channels() < 1 || h.channels() > limits.max_channels) {
    return absl::InvalidArgumentError(
        absl::StrCat("channels ", h.channels(), " outside [1, ", limits.max_channels, "]"));
  }
  switch (h.sample_format()) {
    case dance::v1::SAMPLE_FORMAT_F32LE: v.format = PcmFormat::kF32Le; break;
    case dance::v1::SAMPLE_FORMAT_S16LE: v.format = PcmFormat::kS16Le; break;
    default: return absl::InvalidArgumentError("sample_format must be F32LE or S16LE");
  }
  if (h.client_name().size() > 64) return absl::InvalidArgumentError("client_name longer than 64 bytes");
  absl::StatusOr<StyleMix> style = StyleFromProto(h.style(), model);
  if (!style.ok()) return style.status();
  v.config.style = *std::move(style);
  if (h.has_sampling()) {
    absl::StatusOr<SamplingConfig> s = SamplingFromProto(h.sampling());
    if (!s.ok()) return s.status();
    v.config.sampling = *s;
  }
  v.config.sample_rate_hz = h.sample_rate_hz();
  v.config.channels = h.channels();
  v.config.seed = h.seed();
  v.client_name = h.client_name();
  v.omit_rotations = h.omit_rotations();
  v.config.foot_lock = !h.raw_feet();
  return v;
}

absl::Status ValidateChunk(size_t pcm_bytes, const ValidatedHeader& header, const StreamLimits& limits) {
  const size_t frame_bytes = (header.format == PcmFormat::kF32Le ? 4 : 2) * header.config.channels;
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

namespace {

absl::Status StyleJsonToProto(const json& j, google::protobuf::RepeatedPtrField<dance::v1::StyleWeight>* out) {
  if (j.is_string()) {
    dance::v1::StyleWeight* w = out->Add();
    w->set_name(j.get<std::string>());
    w->set_weight(1.0f);
    return absl::OkStatus();
  }
  if (!j.is_array()) return absl::InvalidArgumentError("style must be a string or a list of {name, weight}");
  for (const json& e : j) {
    if (!e.is_object() || !e.contains("name") || !e["name"].is_string()) {
      return absl::InvalidArgumentError("style entries need a string 'name'");
    }
    dance::v1::StyleWeight* w = out->Add();
    w->set_name(e["name"].get<std::string>());
    w->set_weight(e.contains("weight") && e["weight"].is_number() ? e["weight"].get<float>() : 1.0f);
  }
  return absl::OkStatus();
}

template <typename T>
absl::Status Number(const json& j, const char* key, T* out) {
  if (!j.contains(key)) return absl::OkStatus();
  if (!j[key].is_number()) return absl::InvalidArgumentError(absl::StrCat("'", key, "' must be a number"));
  *out = j[key].get<T>();
  return absl::OkStatus();
}

absl::Status SamplingJson(const json& j, dance::v1::Sampling* s, bool* any) {
  float t = 1.0f, p = 0.0f, g = 0.0f;  // top_p, guidance absent: 0, the model's default
  int k = 0;
  for (const char* key : {"temperature", "top_k", "top_p", "guidance", "period_lock", "music_guidance"}) {
    if (j.contains(key)) *any = true;
  }
  absl::Status st;
  st.Update(Number(j, "temperature", &t));
  st.Update(Number(j, "top_k", &k));
  st.Update(Number(j, "top_p", &p));
  st.Update(Number(j, "guidance", &g));
  s->set_temperature(t);
  s->set_top_k(k);
  s->set_top_p(p);
  s->set_guidance(g);
  if (j.contains("period_lock")) {  // absent: the model's default
    float lock = 0.0f;
    st.Update(Number(j, "period_lock", &lock));
    s->set_period_lock(lock);
  }
  if (j.contains("music_guidance")) {  // absent: the model's default
    float m = 1.0f;
    st.Update(Number(j, "music_guidance", &m));
    s->set_music_guidance(m);
  }
  return st;
}

}  // namespace

absl::StatusOr<dance::v1::StreamHeader> HeaderFromJson(const json& j) {
  dance::v1::StreamHeader h;
  int rate = 0, channels = 1;
  uint64_t seed = 0;
  absl::Status st;
  st.Update(Number(j, "sample_rate", &rate));
  st.Update(Number(j, "channels", &channels));
  st.Update(Number(j, "seed", &seed));
  if (!st.ok()) return st;
  h.set_sample_rate_hz(rate);
  h.set_channels(channels);
  h.set_seed(seed);
  h.set_sample_format(dance::v1::SAMPLE_FORMAT_F32LE);
  if (j.contains("style")) {
    absl::Status s = StyleJsonToProto(j["style"], h.mutable_style());
    if (!s.ok()) return s;
  }
  bool any = false;
  dance::v1::Sampling sampling;
  absl::Status s = SamplingJson(j, &sampling, &any);
  if (!s.ok()) return s;
  if (any) *h.mutable_sampling() = sampling;
  if (j.contains("client_name") && j["client_name"].is_string()) h.set_client_name(j["client_name"].get<std::string>());
  if (j.contains("omit_rotations") && j["omit_rotations"].is_boolean()) h.set_omit_rotations(j["omit_rotations"].get<bool>());
  if (j.contains("raw_feet") && j["raw_feet"].is_boolean()) h.set_raw_feet(j["raw_feet"].get<bool>());
  return h;
}

absl::StatusOr<dance::v1::Control> ControlFromJson(const json& j) {
  dance::v1::Control c;
  if (j.contains("style")) {
    absl::Status s = StyleJsonToProto(j["style"], c.mutable_style());
    if (!s.ok()) return s;
  }
  bool any = false;
  dance::v1::Sampling sampling;
  absl::Status s = SamplingJson(j, &sampling, &any);
  if (!s.ok()) return s;
  if (any) *c.mutable_sampling() = sampling;
  return c;
}

nlohmann::json ModelToJson(const ModelDescription& m) {
  return json{{"model_id", m.model_id},       {"latency_ms", m.latency_ms}, {"fps", m.fps},
              {"joint_names", m.joint_names}, {"parents", m.parents},       {"rest_offsets", m.rest_offsets},
              {"styles", m.styles}, {"default_period_lock", m.default_period_lock},
              {"style_period_lock", m.style_period_lock},
              {"default_guidance", m.default_guidance}, {"default_top_p", m.default_top_p},
              {"default_music_guidance", m.default_music_guidance}};
}

nlohmann::json SummaryToJson(const dance::v1::SessionSummary& s) {
  json style = json::array();
  for (const auto& w : s.style()) style.push_back({{"name", w.name()}, {"weight", w.weight()}});
  return json{{"session_id", s.session_id()}, {"client_name", s.client_name()},
              {"started_unix_ms", s.started_unix_ms()}, {"frames", s.frames()},
              {"audio_ms", s.audio_ms()}, {"viewers", s.viewers()}, {"style", style}};
}

std::string UpdateToJson(const dance::v1::DanceUpdate& u) {
  json j;
  switch (u.kind_case()) {
    case dance::v1::DanceUpdate::kInfo: {
      const auto& i = u.info();
      j = {{"type", "info"}, {"session_id", i.session_id()}, {"model_id", i.model_id()}, {"fps", i.fps()},
           {"latency_ms", i.latency_ms()},
           {"joint_names", std::vector<std::string>(i.skeleton().joint_names().begin(), i.skeleton().joint_names().end())},
           {"parents", std::vector<int>(i.skeleton().parents().begin(), i.skeleton().parents().end())},
           {"rest_offsets", std::vector<float>(i.skeleton().rest_offsets().begin(), i.skeleton().rest_offsets().end())},
           {"styles", std::vector<std::string>(i.styles().begin(), i.styles().end())}};
      break;
    }
    case dance::v1::DanceUpdate::kFrame: {
      const auto& f = u.frame();
      j = {{"type", "frame"}, {"index", f.index()}, {"time_ms", f.time_ms()},
           {"positions", std::vector<float>(f.positions().begin(), f.positions().end())},
           {"rotations", std::vector<float>(f.rotations().begin(), f.rotations().end())},
           {"upper_code", f.upper_code()}, {"lower_code", f.lower_code()},
           {"dropped_before", f.dropped_before()}};
      break;
    }
    case dance::v1::DanceUpdate::kEvent: {
      const auto& e = u.event();
      if (e.kind() == dance::v1::Event::KIND_BEAT) {
        j = {{"type", "beat"}, {"time_ms", e.time_ms()}};
      } else {
        j = {{"type", "event"},
             {"kind", e.kind() == dance::v1::Event::KIND_CONTROL_APPLIED ? "control_applied" : "warning"},
             {"time_ms", e.time_ms()}, {"frame_index", e.frame_index()}, {"message", e.message()}};
      }
      break;
    }
    case dance::v1::DanceUpdate::kEnd:
      j = {{"type", "end"}, {"frames", u.end().frames()}, {"audio_ms", u.end().audio_ms()},
           {"reason", u.end().reason()}};
      break;
    default:
      j = {{"type", "unknown"}};
  }
  return j.dump(-1, ' ', false, json::error_handler_t::replace);
}

}  // namespace dance::server
