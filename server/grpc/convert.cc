#include "server/grpc/convert.h"

#include <string>
#include <utility>

namespace dance::server {
namespace {

// Two wire forms per update: frames with and without rotations. Other kinds always use the first.
int ProtoSlot(bool with_rotations) {
  static const int full = ReserveEncodingSlot();
  static const int bare = ReserveEncodingSlot();
  return with_rotations ? full : bare;
}

dance::v1::Event::Kind EventKindToProto(EventKind kind) {
  switch (kind) {
    case EventKind::kBeat: return dance::v1::Event::KIND_BEAT;
    case EventKind::kControlApplied: return dance::v1::Event::KIND_CONTROL_APPLIED;
    case EventKind::kWarning: return dance::v1::Event::KIND_WARNING;
  }
  return dance::v1::Event::KIND_UNSPECIFIED;
}

dance::v1::DanceUpdate Encode(const Update& update, bool with_rotations) {
  dance::v1::DanceUpdate u;
  if (const InfoUpdate* info = update.info()) {
    const ModelDescription& m = info->model;
    dance::v1::SessionInfo* si = u.mutable_info();
    si->set_session_id(info->session_id);
    si->set_model_id(m.model_id);
    si->set_latency_ms(m.latency_ms);
    si->set_fps(m.fps);
    SkeletonToProto(m, si->mutable_skeleton());
    for (const std::string& s : m.styles) si->add_styles(s);
    si->set_samples_per_step(m.samples_per_step);
    si->set_frames_per_step(m.frames_per_step);
    si->set_pose_latency_ms(m.pose_latency_ms);
  } else if (const FrameUpdate* frame = update.frame()) {
    const FrameData& f = frame->pose;
    dance::v1::PoseFrame* pf = u.mutable_frame();
    pf->set_index(f.index);
    pf->set_time_ms(f.time_s * 1000.0);
    pf->mutable_positions()->Add(f.positions.begin(), f.positions.end());
    if (with_rotations) pf->mutable_rotations()->Add(f.rotations.begin(), f.rotations.end());
    pf->set_upper_code(f.upper_code);
    pf->set_lower_code(f.lower_code);
    pf->set_trigger_sample_end(frame->trigger_sample_end);
    pf->set_server_time_us(frame->server_time_us);
  } else if (const EventUpdate* event = update.event()) {
    dance::v1::Event* e = u.mutable_event();
    e->set_kind(EventKindToProto(event->kind));
    e->set_frame_index(event->frame_index);
    e->set_time_ms(event->time_ms);
    e->set_message(event->message);
  } else if (const EndUpdate* end = update.end()) {
    dance::v1::StreamEnd* e = u.mutable_end();
    e->set_frames(end->frames);
    e->set_audio_ms(end->audio_ms);
    e->set_reason(end->reason);
  }
  return u;
}

}  // namespace

StyleMix StyleFromProto(const google::protobuf::RepeatedPtrField<dance::v1::StyleWeight>& style) {
  StyleMix mix;
  mix.reserve(static_cast<size_t>(style.size()));
  for (const dance::v1::StyleWeight& w : style) mix.emplace_back(w.name(), w.weight());
  return mix;
}

SamplingRequest SamplingFromProto(const dance::v1::Sampling& s) {
  SamplingRequest r;
  r.temperature = s.temperature();
  r.top_k = s.top_k();
  r.top_p = s.top_p();
  r.guidance = s.guidance();
  if (s.has_period_lock()) r.period_lock = s.period_lock();
  if (s.has_music_guidance()) r.music_guidance = s.music_guidance();
  return r;
}

StreamRequest StreamRequestFromProto(const dance::v1::StreamHeader& h) {
  StreamRequest r;
  r.sample_rate_hz = h.sample_rate_hz();
  r.channels = h.channels();
  switch (h.sample_format()) {
    case dance::v1::SAMPLE_FORMAT_F32LE: r.format = PcmFormat::kF32Le; break;
    case dance::v1::SAMPLE_FORMAT_S16LE: r.format = PcmFormat::kS16Le; break;
    default: break;  // refused by ValidateStream
  }
  r.style = StyleFromProto(h.style());
  r.seed = h.seed();
  if (h.has_sampling()) r.sampling = SamplingFromProto(h.sampling());
  r.client_name = h.client_name();
  r.omit_rotations = h.omit_rotations();
  r.raw_feet = h.raw_feet();
  if (h.has_controls()) r.controls = ControlsFromProto(h.controls());
  return r;
}

namespace {

MotionSpec MotionFromProto(const dance::v1::Motion& m) {
  MotionSpec out;
  out.positions.assign(m.positions().begin(), m.positions().end());
  out.file = m.file();
  out.start_s = m.start_ms() / 1000.0;
  for (double t : m.times_ms()) out.times_s.push_back(t / 1000.0);
  return out;
}

PathPointSpec PathPointFromProto(const dance::v1::PathPoint& p) {
  PathPointSpec out;
  out.t_s = p.t_ms() / 1000.0;
  out.x = p.x();
  out.z = p.z();
  if (p.has_facing()) out.facing = p.facing();
  return out;
}

}  // namespace

ControlSpec ControlsFromProto(const dance::v1::MotionControls& c) {
  ControlSpec out;
  out.seed = MotionFromProto(c.seed());
  out.given_upper = MotionFromProto(c.given_upper());
  out.given_lower = MotionFromProto(c.given_lower());
  out.keyframes = MotionFromProto(c.keyframes());
  out.inpaint = MotionFromProto(c.inpaint());
  for (const dance::v1::MaskSpan& m : c.inpaint_known()) {
    out.inpaint_known.push_back({m.start_ms() / 1000.0, m.end_ms() / 1000.0, {m.joints().begin(), m.joints().end()}});
  }
  for (const dance::v1::PathPoint& p : c.trajectory()) out.trajectory.push_back(PathPointFromProto(p));
  return out;
}

SteerTarget SteerFromProto(const dance::v1::SteerTarget& s) {
  SteerTarget out;
  if (s.has_point()) {
    const PathPointSpec p = PathPointFromProto(s.point());
    out.kind = SteerTarget::Kind::kPoint;
    out.t_s = p.t_s;
    out.x = p.x;
    out.z = p.z;
    out.facing = p.facing;
  } else {
    // A velocity, or (neither set) a zero velocity: the steering released.
    out.kind = SteerTarget::Kind::kVelocity;
    out.x = s.velocity().x();
    out.z = s.velocity().z();
    if (s.velocity().has_facing()) out.facing = s.velocity().facing();
    out.hold_s = s.velocity().hold_ms() == 0.0 ? 1.0 : s.velocity().hold_ms() / 1000.0;
  }
  return out;
}

PoseRequest PoseFromProto(const dance::v1::PoseInput& p) {
  PoseRequest out;
  out.time_ms = p.time_ms();
  out.positions.assign(p.positions().begin(), p.positions().end());
  switch (p.part()) {
    case dance::v1::BODY_PART_UPPER: out.part = BodyPart::kUpper; break;
    case dance::v1::BODY_PART_LOWER: out.part = BodyPart::kLower; break;
    case dance::v1::BODY_PART_ALL: out.part = BodyPart::kAll; break;
    default: out.part = BodyPart::kUnspecified; break;
  }
  return out;
}

ControlRequest ControlRequestFromProto(const dance::v1::Control& c) {
  ControlRequest r;
  r.style = StyleFromProto(c.style());
  if (c.has_sampling()) r.sampling = SamplingFromProto(c.sampling());
  if (c.has_controls()) r.controls = ControlsFromProto(c.controls());
  if (c.has_steer()) r.steer = SteerFromProto(c.steer());
  return r;
}

absl::StatusOr<ValidatedStream> ValidateHeader(const dance::v1::StreamHeader& header, const ModelDescription& model,
                                               const StreamLimits& limits) {
  return ValidateStream(StreamRequestFromProto(header), model, limits);
}

const dance::v1::DanceUpdate& UpdateToProto(const Update& update, bool with_rotations) {
  const bool rotations = with_rotations || !update.is_frame();  // one form for the other kinds
  return update.Encoding<dance::v1::DanceUpdate>(ProtoSlot(rotations), [&] { return Encode(update, rotations); });
}

void SummaryToProto(const SessionSummary& s, dance::v1::SessionSummary* out) {
  out->set_session_id(s.session_id);
  out->set_client_name(s.client_name);
  out->set_started_unix_ms(s.started_unix_ms);
  out->set_frames(s.frames);
  out->set_audio_ms(s.audio_ms);
  out->set_viewers(s.viewers);
  for (const auto& [name, weight] : s.style) {
    dance::v1::StyleWeight* w = out->add_style();
    w->set_name(name);
    w->set_weight(weight);
  }
}

void SkeletonToProto(const ModelDescription& model, dance::v1::Skeleton* out) {
  for (const std::string& n : model.joint_names) out->add_joint_names(n);
  for (int p : model.parents) out->add_parents(p);
  for (float v : model.rest_offsets) out->add_rest_offsets(v);
}

void ModelToProto(const ModelDescription& m, dance::v1::ModelInfo* out) {
  out->set_model_id(m.model_id);
  out->set_latency_ms(m.latency_ms);
  out->set_fps(m.fps);
  SkeletonToProto(m, out->mutable_skeleton());
  for (const std::string& s : m.styles) out->add_styles(s);
  out->set_default_period_lock(m.default_period_lock);
  for (const auto& [style, lock] : m.style_period_lock) (*out->mutable_style_period_lock())[style] = lock;
  out->set_default_guidance(m.default_guidance);
  out->set_default_music_guidance(m.default_music_guidance);
  out->set_default_top_p(m.default_top_p);
  out->set_pose_latency_ms(m.pose_latency_ms);
}

}  // namespace dance::server
