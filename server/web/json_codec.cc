#include "server/web/json_codec.h"

#include <optional>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"

namespace dance::server {
namespace {

using nlohmann::json;

// Two wire forms per update: frames with and without rotations. Other kinds always use the first.
int JsonSlot(bool with_rotations) {
  static const int full = ReserveEncodingSlot();
  static const int bare = ReserveEncodingSlot();
  return with_rotations ? full : bare;
}

// An absent key leaves *out as it is.
template <typename T>
absl::Status Number(const json& j, const char* key, T* out) {
  if (!j.contains(key)) return absl::OkStatus();
  if (!j[key].is_number()) return absl::InvalidArgumentError(absl::StrCat("'", key, "' must be a number"));
  *out = j[key].get<T>();
  return absl::OkStatus();
}

// "style": "name" or [{"name": ..., "weight": ...}, ...] (weight 1 when absent or not a number).
absl::StatusOr<StyleMix> StyleFromJson(const json& j) {
  StyleMix mix;
  if (j.is_string()) {
    mix.emplace_back(j.get<std::string>(), 1.0f);
    return mix;
  }
  if (!j.is_array()) return absl::InvalidArgumentError("style must be a string or a list of {name, weight}");
  for (const json& e : j) {
    if (!e.is_object() || !e.contains("name") || !e["name"].is_string()) {
      return absl::InvalidArgumentError("style entries need a string 'name'");
    }
    mix.emplace_back(e["name"].get<std::string>(),
                     e.contains("weight") && e["weight"].is_number() ? e["weight"].get<float>() : 1.0f);
  }
  return mix;
}

// The sampling keys of a start or control message; nullopt if it has none. A key of the wrong type is
// an error (the first one, in the order below).
absl::StatusOr<std::optional<SamplingRequest>> SamplingFromJson(const json& j) {
  bool any = false;
  for (const char* key : {"temperature", "top_k", "top_p", "guidance", "period_lock", "music_guidance"}) {
    if (j.contains(key)) any = true;
  }
  SamplingRequest s;  // temperature 1; top_p and guidance 0, the model's defaults
  absl::Status st;
  st.Update(Number(j, "temperature", &s.temperature));
  st.Update(Number(j, "top_k", &s.top_k));
  st.Update(Number(j, "top_p", &s.top_p));
  st.Update(Number(j, "guidance", &s.guidance));
  if (j.contains("period_lock")) {  // absent: the model's default
    float lock = 0.0f;
    st.Update(Number(j, "period_lock", &lock));
    s.period_lock = lock;
  }
  if (j.contains("music_guidance")) {  // absent: the model's default
    float m = 1.0f;
    st.Update(Number(j, "music_guidance", &m));
    s.music_guidance = m;
  }
  if (!st.ok()) return st;
  if (!any) return std::optional<SamplingRequest>();
  return std::optional<SamplingRequest>(s);
}

const char* EventKindName(EventKind kind) {
  return kind == EventKind::kControlApplied ? "control_applied" : "warning";
}

std::string Encode(const Update& update, bool with_rotations, int64_t dropped_before) {
  json j;
  if (const InfoUpdate* info = update.info()) {
    const ModelDescription& m = info->model;
    j = {{"type", "info"},           {"session_id", info->session_id}, {"model_id", m.model_id},
         {"fps", m.fps},             {"latency_ms", m.latency_ms},     {"joint_names", m.joint_names},
         {"parents", m.parents},     {"rest_offsets", m.rest_offsets}, {"styles", m.styles}};
  } else if (const FrameUpdate* frame = update.frame()) {
    const FrameData& f = frame->pose;
    j = {{"type", "frame"},
         {"index", f.index},
         {"time_ms", f.time_s * 1000.0},
         {"positions", f.positions},
         {"rotations", with_rotations ? json(f.rotations) : json::array()},
         {"upper_code", f.upper_code},
         {"lower_code", f.lower_code},
         {"dropped_before", dropped_before}};
  } else if (const EventUpdate* e = update.event()) {
    if (e->kind == EventKind::kBeat) {
      j = {{"type", "beat"}, {"time_ms", e->time_ms}};
    } else {
      j = {{"type", "event"},
           {"kind", EventKindName(e->kind)},
           {"time_ms", e->time_ms},
           {"frame_index", e->frame_index},
           {"message", e->message}};
    }
  } else if (const EndUpdate* end = update.end()) {
    j = {{"type", "end"}, {"frames", end->frames}, {"audio_ms", end->audio_ms}, {"reason", end->reason}};
  } else {
    j = {{"type", "unknown"}};
  }
  return j.dump(-1, ' ', false, json::error_handler_t::replace);
}

// {"positions": [...], "file": "...", "start_ms": MS, "times_ms": [...]}
absl::StatusOr<MotionSpec> MotionFromJson(const json& j, const char* name) {
  MotionSpec m;
  if (!j.is_object()) return absl::InvalidArgumentError(absl::StrCat("controls.", name, " must be an object"));
  if (j.contains("positions")) {
    if (!j["positions"].is_array()) {
      return absl::InvalidArgumentError(absl::StrCat("controls.", name, ".positions must be a list of numbers"));
    }
    m.positions.reserve(j["positions"].size());
    for (const json& v : j["positions"]) {
      if (!v.is_number()) {
        return absl::InvalidArgumentError(absl::StrCat("controls.", name, ".positions must be a list of numbers"));
      }
      m.positions.push_back(v.get<float>());
    }
  }
  if (j.contains("file")) {
    if (!j["file"].is_string()) {
      return absl::InvalidArgumentError(absl::StrCat("controls.", name, ".file must be the file's text"));
    }
    m.file = j["file"].get<std::string>();
  }
  double start_ms = 0.0;
  if (absl::Status s = Number(j, "start_ms", &start_ms); !s.ok()) return s;
  m.start_s = start_ms / 1000.0;
  if (j.contains("times_ms")) {
    if (!j["times_ms"].is_array()) return absl::InvalidArgumentError(absl::StrCat("controls.", name, ".times_ms must be a list"));
    for (const json& t : j["times_ms"]) {
      if (!t.is_number()) return absl::InvalidArgumentError(absl::StrCat("controls.", name, ".times_ms must be numbers"));
      m.times_s.push_back(t.get<double>() / 1000.0);
    }
  }
  return m;
}

// {"t_ms", "x", "z", "facing" (optional)}
absl::StatusOr<PathPointSpec> PathPointFromJson(const json& j, const char* what) {
  if (!j.is_object() || !j.contains("t_ms") || !j.contains("x") || !j.contains("z")) {
    return absl::InvalidArgumentError(absl::StrCat(what, " needs t_ms, x and z"));
  }
  PathPointSpec p;
  double t_ms = 0.0;
  absl::Status st;
  st.Update(Number(j, "t_ms", &t_ms));
  st.Update(Number(j, "x", &p.x));
  st.Update(Number(j, "z", &p.z));
  if (j.contains("facing")) {
    float f = 0.0f;
    st.Update(Number(j, "facing", &f));
    p.facing = f;
  }
  if (!st.ok()) return absl::InvalidArgumentError(absl::StrCat(what, ": ", st.message()));
  p.t_s = t_ms / 1000.0;
  return p;
}

}  // namespace

absl::StatusOr<ControlSpec> ControlsFromJson(const json& j) {
  if (!j.is_object()) return absl::InvalidArgumentError("controls must be an object");
  ControlSpec c;
  for (const auto& [key, m] : {std::pair{"seed", &c.seed}, std::pair{"given_upper", &c.given_upper},
                               std::pair{"given_lower", &c.given_lower}, std::pair{"keyframes", &c.keyframes},
                               std::pair{"inpaint", &c.inpaint}}) {
    if (!j.contains(key)) continue;
    absl::StatusOr<MotionSpec> motion = MotionFromJson(j[key], key);
    if (!motion.ok()) return motion.status();
    *m = *std::move(motion);
  }
  if (j.contains("inpaint_known")) {
    if (!j["inpaint_known"].is_array()) return absl::InvalidArgumentError("controls.inpaint_known must be a list");
    for (const json& k : j["inpaint_known"]) {
      if (!k.is_object() || !k.contains("start_ms") || !k.contains("end_ms") || !k.contains("joints") ||
          !k["joints"].is_array()) {
        return absl::InvalidArgumentError("controls.inpaint_known entries need start_ms, end_ms and joints");
      }
      MaskSpanSpec span;
      double a = 0.0, b = 0.0;
      absl::Status st;
      st.Update(Number(k, "start_ms", &a));
      st.Update(Number(k, "end_ms", &b));
      if (!st.ok()) return absl::InvalidArgumentError(absl::StrCat("controls.inpaint_known: ", st.message()));
      span.start_s = a / 1000.0;
      span.end_s = b / 1000.0;
      for (const json& n : k["joints"]) {
        if (!n.is_string()) return absl::InvalidArgumentError("controls.inpaint_known: joints are names");
        span.joints.push_back(n.get<std::string>());
      }
      c.inpaint_known.push_back(std::move(span));
    }
  }
  if (j.contains("trajectory")) {
    if (!j["trajectory"].is_array()) return absl::InvalidArgumentError("controls.trajectory must be a list");
    for (const json& p : j["trajectory"]) {
      absl::StatusOr<PathPointSpec> q = PathPointFromJson(p, "controls.trajectory point");
      if (!q.ok()) return q.status();
      c.trajectory.push_back(*q);
    }
  }
  return c;
}

absl::StatusOr<SteerTarget> SteerFromJson(const json& j) {
  SteerTarget t;
  if (j.is_object() && j.contains("point")) {
    absl::StatusOr<PathPointSpec> p = PathPointFromJson(j["point"], "steer.point");
    if (!p.ok()) return p.status();
    t.kind = SteerTarget::Kind::kPoint;
    t.t_s = p->t_s;
    t.x = p->x;
    t.z = p->z;
    t.facing = p->facing;
    return t;
  }
  if (!j.is_object() || !j.contains("velocity") || !j["velocity"].is_object()) {
    return absl::InvalidArgumentError("steer needs a point {t_ms, x, z} or a velocity {x, z}");
  }
  const json& v = j["velocity"];
  t.kind = SteerTarget::Kind::kVelocity;
  double hold_ms = 1000.0;
  absl::Status st;
  st.Update(Number(v, "x", &t.x));
  st.Update(Number(v, "z", &t.z));
  st.Update(Number(v, "hold_ms", &hold_ms));
  if (v.contains("facing")) {
    float f = 0.0f;
    st.Update(Number(v, "facing", &f));
    t.facing = f;
  }
  if (!st.ok()) return absl::InvalidArgumentError(absl::StrCat("steer.velocity: ", st.message()));
  t.hold_s = hold_ms / 1000.0;
  return t;
}

absl::StatusOr<std::vector<PoseRequest>> PosesFromJson(const json& j) {
  if (!j.contains("poses") || !j["poses"].is_array()) return absl::InvalidArgumentError("poses must be a list");
  std::vector<PoseRequest> out;
  for (const json& p : j["poses"]) {
    if (!p.is_object()) return absl::InvalidArgumentError("a pose must be an object");
    PoseRequest r;
    if (absl::Status s = Number(p, "time_ms", &r.time_ms); !s.ok()) return s;
    if (p.contains("positions") && p["positions"].is_array()) {
      for (const json& v : p["positions"]) {
        if (!v.is_number()) return absl::InvalidArgumentError("poses: positions must be numbers");
        r.positions.push_back(v.get<float>());
      }
    }
    const std::string part = p.contains("part") && p["part"].is_string() ? p["part"].get<std::string>() : "";
    r.part = part == "upper" ? BodyPart::kUpper : part == "lower" ? BodyPart::kLower
           : part == "all" ? BodyPart::kAll : BodyPart::kUnspecified;
    out.push_back(std::move(r));
  }
  return out;
}

absl::StatusOr<StreamRequest> StreamRequestFromJson(const json& j) {
  StreamRequest r;
  r.channels = 1;
  absl::Status st;
  st.Update(Number(j, "sample_rate", &r.sample_rate_hz));
  st.Update(Number(j, "channels", &r.channels));
  st.Update(Number(j, "seed", &r.seed));
  if (!st.ok()) return st;
  r.format = PcmFormat::kF32Le;
  if (j.contains("style")) {
    absl::StatusOr<StyleMix> style = StyleFromJson(j["style"]);
    if (!style.ok()) return style.status();
    r.style = *std::move(style);
  }
  absl::StatusOr<std::optional<SamplingRequest>> sampling = SamplingFromJson(j);
  if (!sampling.ok()) return sampling.status();
  r.sampling = *sampling;
  if (j.contains("client_name") && j["client_name"].is_string()) r.client_name = j["client_name"].get<std::string>();
  if (j.contains("omit_rotations") && j["omit_rotations"].is_boolean()) r.omit_rotations = j["omit_rotations"].get<bool>();
  if (j.contains("raw_feet") && j["raw_feet"].is_boolean()) r.raw_feet = j["raw_feet"].get<bool>();
  if (j.contains("controls")) {
    absl::StatusOr<ControlSpec> c = ControlsFromJson(j["controls"]);
    if (!c.ok()) return c.status();
    r.controls = *std::move(c);
  }
  return r;
}

absl::StatusOr<ControlRequest> ControlRequestFromJson(const json& j) {
  ControlRequest c;
  if (j.contains("style")) {
    absl::StatusOr<StyleMix> style = StyleFromJson(j["style"]);
    if (!style.ok()) return style.status();
    c.style = *std::move(style);
  }
  absl::StatusOr<std::optional<SamplingRequest>> sampling = SamplingFromJson(j);
  if (!sampling.ok()) return sampling.status();
  c.sampling = *sampling;
  if (j.contains("controls")) {
    absl::StatusOr<ControlSpec> controls = ControlsFromJson(j["controls"]);
    if (!controls.ok()) return controls.status();
    c.controls = *std::move(controls);
  }
  if (j.contains("steer")) {
    absl::StatusOr<SteerTarget> steer = SteerFromJson(j["steer"]);
    if (!steer.ok()) return steer.status();
    c.steer = *steer;
  }
  return c;
}

absl::string_view UpdateToJson(const Update& update, bool with_rotations, int64_t dropped_before,
                               std::string* scratch) {
  if (dropped_before != 0 && update.is_frame()) {
    *scratch = Encode(update, with_rotations, dropped_before);
    return *scratch;
  }
  const bool rotations = with_rotations || !update.is_frame();  // one form for the other kinds
  return update.Encoding<std::string>(JsonSlot(rotations), [&] { return Encode(update, rotations, 0); });
}

absl::StatusOr<EditConfig> EditConfigFromJson(const json& j) {
  EditConfig c;
  absl::Status st;
  if (j.contains("audio_name")) {
    if (!j["audio_name"].is_string()) return absl::InvalidArgumentError("'audio_name' must be a string");
    c.audio_name = j["audio_name"].get<std::string>().substr(0, 200);
  }
  if (j.contains("style")) {
    absl::StatusOr<StyleMix> style = StyleFromJson(j["style"]);
    if (!style.ok()) return style.status();
    c.style = *std::move(style);
  }
  if (j.contains("seed") && !(j["seed"].is_number_unsigned() || (j["seed"].is_number_integer() && j["seed"].get<int64_t>() >= 0))) {
    return absl::InvalidArgumentError("'seed' must be a non-negative integer");
  }
  st.Update(Number(j, "seed", &c.seed));
  if (j.contains("steps") && !j["steps"].is_number_integer()) return absl::InvalidArgumentError("'steps' must be an integer");
  st.Update(Number(j, "steps", &c.steps));
  st.Update(Number(j, "guidance", &c.guidance));
  st.Update(Number(j, "overlap_s", &c.overlap_s));
  if (!st.ok()) return st;
  if (j.contains("raw_feet")) {
    if (!j["raw_feet"].is_boolean()) return absl::InvalidArgumentError("'raw_feet' must be true or false");
    c.foot_lock = !j["raw_feet"].get<bool>();
  }
  if (j.contains("controls")) {
    absl::StatusOr<ControlSpec> controls = ControlsFromJson(j["controls"]);
    if (!controls.ok()) return controls.status();
    c.controls = *std::move(controls);
  }
  return c;
}

std::string EditEventToJson(const EditEvent& e, const EditorDescription& editor, bool with_rotations) {
  switch (e.kind) {
    case EditEvent::Kind::kQueued:
      return json{{"type", "queued"}, {"position", e.position}}.dump();
    case EditEvent::Kind::kProgress:
      return json{{"type", "progress"}, {"steps_done", e.progress.steps_done},
                  {"steps_total", e.progress.steps_total}}.dump();
    case EditEvent::Kind::kDone:
      break;
  }
  if (!e.status.ok() || e.output == nullptr) return ErrorToJson(e.status.ok() ? absl::InternalError("no result") : e.status);
  const EditOutput& out = *e.output;
  json frames = json::array();
  for (const FrameData& f : out.frames) {
    json jf = {{"index", f.index}, {"time_ms", f.time_s * 1000.0},
               {"positions", std::vector<float>(f.positions.begin(), f.positions.end())}};
    if (with_rotations) jf["rotations"] = std::vector<float>(f.rotations.begin(), f.rotations.end());
    frames.push_back(std::move(jf));
  }
  return json{{"type", "result"}, {"model_id", editor.model_id}, {"fps", 30.0}, {"windows", out.windows},
              {"steps", out.steps}, {"guidance", out.guidance}, {"overlap_s", out.overlap_s},
              {"audio_ms", out.audio_s * 1000.0}, {"compute_ms", e.compute_s * 1000.0},
              {"skeleton", {{"joint_names", editor.joint_names}, {"parents", editor.parents},
                            {"rest_offsets", editor.rest_offsets}}},
              {"frames", std::move(frames)}}
      .dump();
}

json EditorToJson(const EditJobs& jobs) {
  const EditorDescription& d = jobs.editor()->Describe();
  return json{{"model_id", d.model_id}, {"styles", d.styles}, {"default_steps", d.default_steps},
              {"default_guidance", d.default_guidance}, {"default_overlap_s", d.default_overlap_s},
              {"window_s", d.window_s}, {"workers", jobs.options().workers},
              {"max_queued", jobs.options().max_queued}, {"max_per_client", jobs.options().max_per_client},
              {"max_audio_s", jobs.options().max_audio_s}};
}

std::string ErrorToJson(const absl::Status& status) {
  return json{{"type", "error"},
              {"code", absl::StatusCodeToString(status.code())},
              {"message", std::string(status.message())}}
      .dump();
}

json ModelToJson(const ModelDescription& m) {
  return json{{"model_id", m.model_id},       {"latency_ms", m.latency_ms}, {"fps", m.fps},
              {"joint_names", m.joint_names}, {"parents", m.parents},       {"rest_offsets", m.rest_offsets},
              {"styles", m.styles}, {"default_period_lock", m.default_period_lock},
              {"style_period_lock", m.style_period_lock},
              {"default_guidance", m.default_guidance}, {"default_top_p", m.default_top_p},
              {"pose_latency_ms", m.pose_latency_ms},
              {"default_music_guidance", m.default_music_guidance}};
}

json SummaryToJson(const SessionSummary& s) {
  json style = json::array();
  for (const auto& [name, weight] : s.style) style.push_back({{"name", name}, {"weight", weight}});
  return json{{"session_id", s.session_id}, {"client_name", s.client_name},
              {"started_unix_ms", s.started_unix_ms}, {"frames", s.frames},
              {"audio_ms", s.audio_ms}, {"viewers", s.viewers}, {"style", style}};
}

}  // namespace dance::server
