#include "engine/runtime/motion_io.h"

#include <cmath>
#include <fstream>
#include <map>
#include <sstream>

#include "Eigen/Geometry"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "nlohmann/json.hpp"

namespace dance::engine {
namespace {

constexpr const char* kSmplNames[kNumJoints] = {
    "pelvis",     "left_hip",       "right_hip",      "spine1",      "left_knee",   "right_knee",
    "spine2",     "left_ankle",     "right_ankle",    "spine3",      "left_foot",   "right_foot",
    "neck",       "left_collar",    "right_collar",   "head",        "left_shoulder", "right_shoulder",
    "left_elbow", "right_elbow",    "left_wrist",     "right_wrist", "left_hand",   "right_hand"};
constexpr double kFps = 30.0;
constexpr double kMaxTimeS = 1e6;  // audio times beyond 11 days are refused (frame indices stay exact)

absl::StatusOr<std::string> ReadText(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError(absl::StrCat("cannot open '", path, "'"));
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

absl::StatusOr<nlohmann::json> ParseJson(const std::string& text, const std::string& path) {
  nlohmann::json doc = nlohmann::json::parse(text, nullptr, /*allow_exceptions=*/false);
  if (doc.is_discarded()) return absl::InvalidArgumentError(absl::StrCat("'", path, "' is not JSON"));
  return doc;
}

// Whether `d` is an object whose "format" is the string `name`. (nlohmann's value() throws on a key of
// another type: every field read here is checked for its type first.)
bool IsFormat(const nlohmann::json& d, const char* name) {
  return d.is_object() && d.contains("format") && d["format"].is_string() && d["format"].get<std::string>() == name;
}

// The number at `key`, `fallback` if absent; InvalidArgument if present and not a number.
absl::StatusOr<double> NumberOr(const nlohmann::json& d, const char* key, double fallback, const std::string& path) {
  if (!d.contains(key)) return fallback;
  if (!d[key].is_number()) return absl::InvalidArgumentError(absl::StrCat("'", path, "': \"", key, "\" is not a number"));
  return d[key].get<double>();
}

// Resamples `in` at `fps` to 30 fps (linear interpolation; the identity at 30).
std::vector<JointPositions> ToThirtyFps(const std::vector<JointPositions>& in, double fps) {
  if (std::abs(fps - kFps) < 1e-3 || in.size() < 2) return in;  // (BVH frame times are rounded)
  const double duration = (in.size() - 1) / fps;
  const size_t n = static_cast<size_t>(std::floor(duration * kFps + 1e-9)) + 1;
  std::vector<JointPositions> out(n);
  for (size_t i = 0; i < n; ++i) {
    const double x = i / kFps * fps;
    const size_t a = std::min(static_cast<size_t>(x), in.size() - 2);
    const float w = static_cast<float>(x - a);
    for (int j = 0; j < kNumJoints; ++j) out[i][j] = in[a][j] + w * (in[a + 1][j] - in[a][j]);
  }
  return out;
}

absl::Status CheckPositions(const std::vector<JointPositions>& p, const std::string& what) {
  if (p.empty()) return absl::InvalidArgumentError(absl::StrCat(what, ": no frames"));
  for (size_t i = 0; i < p.size(); ++i) {
    for (int j = 0; j < kNumJoints; ++j) {
      if (!p[i][j].allFinite() || p[i][j].cwiseAbs().maxCoeff() > 100.0f) {
        return absl::InvalidArgumentError(absl::StrCat(what, ": frame ", i, " joint ", kSmplNames[j],
                                                       " is not a finite position within 100 m"));
      }
    }
  }
  return absl::OkStatus();
}

absl::StatusOr<MotionFile> MotionFromJson(const std::string& text, const std::string& path) {
  absl::StatusOr<nlohmann::json> doc = ParseJson(text, path);
  if (!doc.ok()) return doc.status();
  const nlohmann::json& d = *doc;
  if (!IsFormat(d, "dance-motion/v1")) {
    return absl::InvalidArgumentError(absl::StrCat("'", path, "': not a dance-motion/v1 file (\"format\")"));
  }
  if (d.contains("joint_names")) {
    if (!d["joint_names"].is_array() || d["joint_names"].size() != kNumJoints) {
      return absl::InvalidArgumentError(absl::StrCat("'", path, "': joint_names must list the 24 SMPL joints, got ",
                                                     d["joint_names"].size()));
    }
    for (int j = 0; j < kNumJoints; ++j) {
      if (!d["joint_names"][j].is_string() || d["joint_names"][j].get<std::string>() != kSmplNames[j]) {
        return absl::InvalidArgumentError(absl::StrCat("'", path, "': joint ", j, " is ", d["joint_names"][j].dump(),
                                                       ", expected \"", kSmplNames[j], "\" (SMPL order)"));
      }
    }
  }
  absl::StatusOr<double> fps_or = NumberOr(d, "fps", kFps, path);
  if (!fps_or.ok()) return fps_or.status();
  const double fps = *fps_or;
  if (!(fps >= 1.0 && fps <= 1000.0)) return absl::InvalidArgumentError(absl::StrCat("'", path, "': bad fps"));
  if (!d.contains("positions") || !d["positions"].is_array()) {
    return absl::InvalidArgumentError(absl::StrCat("'", path, "': no \"positions\" array"));
  }
  std::vector<JointPositions> pos;
  for (const nlohmann::json& f : d["positions"]) {
    if (!f.is_array() || f.size() != kNumJoints) {
      return absl::InvalidArgumentError(absl::StrCat("'", path, "': frame ", pos.size(), " has ", f.size(),
                                                     " joints, expected 24"));
    }
    JointPositions& p = pos.emplace_back();
    for (int j = 0; j < kNumJoints; ++j) {
      if (!f[j].is_array() || f[j].size() != 3 || !f[j][0].is_number() || !f[j][1].is_number() ||
          !f[j][2].is_number()) {
        return absl::InvalidArgumentError(absl::StrCat("'", path, "': frame ", pos.size() - 1, " joint ", j,
                                                       " is not [x, y, z]"));
      }
      p[j] = Eigen::Vector3f(f[j][0].get<float>(), f[j][1].get<float>(), f[j][2].get<float>());
    }
  }
  if (absl::Status s = CheckPositions(pos, absl::StrCat("'", path, "'")); !s.ok()) return s;
  MotionFile m;
  m.positions = ToThirtyFps(pos, fps);
  absl::StatusOr<double> offset_or = NumberOr(d, "audio_offset_s", 0.0, path);
  if (!offset_or.ok()) return offset_or.status();
  const double offset = *offset_or;
  if (!std::isfinite(offset) || offset < 0.0 || offset > kMaxTimeS) {
    return absl::InvalidArgumentError(absl::StrCat("'", path, "': audio_offset_s must be in [0, ", kMaxTimeS, "] s"));
  }
  m.first_frame = std::lround(offset * kFps);
  m.offset_s = offset;
  if (d.contains("times_s")) {
    if (!d["times_s"].is_array() || d["times_s"].size() != pos.size()) {
      return absl::InvalidArgumentError(absl::StrCat("'", path, "': times_s must give one time per frame (",
                                                     pos.size(), ")"));
    }
    if (std::abs(fps - kFps) > 1e-6) m.positions = pos;  // keyframes are not resampled: one pose each
    for (const nlohmann::json& t : d["times_s"]) {
      if (!t.is_number() || !std::isfinite(t.get<double>()) || t.get<double>() < 0.0 || t.get<double>() > kMaxTimeS) {
        return absl::InvalidArgumentError(absl::StrCat("'", path, "': times_s must be numbers in [0, ", kMaxTimeS, "] s"));
      }
      m.times_s.push_back(t.get<double>());
    }
  }
  return m;
}

// Rotation of one BVH channel ("Xrotation" ...) by `degrees`.
Eigen::Matrix3d ChannelRotation(char axis, double degrees) {
  const double r = degrees * M_PI / 180.0;
  const Eigen::Vector3d a = axis == 'X' ? Eigen::Vector3d::UnitX() : axis == 'Y' ? Eigen::Vector3d::UnitY()
                                                                                : Eigen::Vector3d::UnitZ();
  return Eigen::AngleAxisd(r, a).toRotationMatrix();
}

}  // namespace

absl::StatusOr<MotionFile> ParseBvh(const std::string& text) {
  struct BvhJoint {
    std::string name;
    int parent = -1;
    Eigen::Vector3d offset = Eigen::Vector3d::Zero();
    std::vector<std::string> channels;
    bool end_site = false;
  };
  std::istringstream in(text);
  std::string tok;
  if (!(in >> tok) || tok != "HIERARCHY") return absl::InvalidArgumentError("BVH: no HIERARCHY");
  std::vector<BvhJoint> joints;
  std::vector<int> stack;
  int pending = -1;
  while (in >> tok && tok != "MOTION") {
    if (tok == "ROOT" || tok == "JOINT" || tok == "End") {
      BvhJoint j;
      j.end_site = tok == "End";
      if (!(in >> j.name)) return absl::InvalidArgumentError("BVH: a joint without a name");
      j.parent = stack.empty() ? -1 : stack.back();
      if (tok == "ROOT" && !joints.empty()) return absl::InvalidArgumentError("BVH: more than one ROOT");
      pending = static_cast<int>(joints.size());
      joints.push_back(j);
    } else if (tok == "{") {
      if (pending < 0) return absl::InvalidArgumentError("BVH: '{' without a joint");
      stack.push_back(pending);
      pending = -1;
    } else if (tok == "}") {
      if (stack.empty()) return absl::InvalidArgumentError("BVH: unbalanced '}'");
      stack.pop_back();
    } else if (tok == "OFFSET") {
      if (stack.empty()) return absl::InvalidArgumentError("BVH: OFFSET outside a joint");
      Eigen::Vector3d& o = joints[stack.back()].offset;
      if (!(in >> o.x() >> o.y() >> o.z())) return absl::InvalidArgumentError("BVH: bad OFFSET");
    } else if (tok == "CHANNELS") {
      int n = 0;
      if (stack.empty() || !(in >> n) || n < 0 || n > 6) return absl::InvalidArgumentError("BVH: bad CHANNELS");
      for (int i = 0; i < n; ++i) {
        std::string c;
        if (!(in >> c)) return absl::InvalidArgumentError("BVH: bad CHANNELS");
        joints[stack.back()].channels.push_back(c);
      }
    } else {
      return absl::InvalidArgumentError(absl::StrCat("BVH: unexpected '", tok, "' in the hierarchy"));
    }
    if (joints.size() > 512) return absl::InvalidArgumentError("BVH: too many joints");
  }
  if (tok != "MOTION" || !stack.empty()) return absl::InvalidArgumentError("BVH: the hierarchy does not close");
  int frames = 0;
  double frame_time = 0.0;
  std::string word;
  if (!(in >> word) || word != "Frames:" || !(in >> frames) || frames <= 0 || frames > 10'000'000) {
    return absl::InvalidArgumentError("BVH: bad 'Frames:'");
  }
  if (!(in >> word >> tok) || word != "Frame" || tok != "Time:" || !(in >> frame_time) || !(frame_time > 0.0)) {
    return absl::InvalidArgumentError("BVH: bad 'Frame Time:'");
  }
  std::map<std::string, int> by_name;
  for (size_t i = 0; i < joints.size(); ++i) {
    if (!joints[i].end_site) by_name[joints[i].name] = static_cast<int>(i);
  }
  std::vector<std::string> missing;
  int smpl[kNumJoints];
  for (int j = 0; j < kNumJoints; ++j) {
    auto it = by_name.find(kSmplNames[j]);
    smpl[j] = it == by_name.end() ? -1 : it->second;
    if (smpl[j] < 0) missing.push_back(kSmplNames[j]);
  }
  if (!missing.empty()) {
    return absl::InvalidArgumentError(absl::StrCat("BVH: not the SMPL 24-joint skeleton; missing joints: ",
                                                   absl::StrJoin(missing, ", ")));
  }
  std::vector<JointPositions> pos(frames);
  std::vector<Eigen::Matrix3d> rot(joints.size());
  std::vector<Eigen::Vector3d> at(joints.size());
  for (int f = 0; f < frames; ++f) {
    for (size_t i = 0; i < joints.size(); ++i) {
      const BvhJoint& j = joints[i];
      Eigen::Vector3d translation = j.offset;
      Eigen::Matrix3d local = Eigen::Matrix3d::Identity();
      for (const std::string& c : j.channels) {
        double v = 0.0;
        if (!(in >> v) || !std::isfinite(v)) {
          return absl::InvalidArgumentError(absl::StrCat("BVH: frame ", f, " has too few or bad values"));
        }
        if (c.size() == 9 && c.substr(1) == "position" && (c[0] == 'X' || c[0] == 'Y' || c[0] == 'Z')) {
          translation[c[0] - 'X'] = v;
        } else if (c.size() == 9 && c.substr(1) == "rotation" && (c[0] == 'X' || c[0] == 'Y' || c[0] == 'Z')) {
          local = local * ChannelRotation(c[0], v);
        } else {
          return absl::InvalidArgumentError(absl::StrCat("BVH: unknown channel '", c, "'"));
        }
      }
      if (j.parent < 0) {
        rot[i] = local;
        at[i] = translation;
      } else {
        rot[i] = rot[j.parent] * local;
        at[i] = at[j.parent] + rot[j.parent] * translation;
      }
    }
    for (int k = 0; k < kNumJoints; ++k) pos[f][k] = at[smpl[k]].cast<float>();
  }
  if (absl::Status s = CheckPositions(pos, "BVH"); !s.ok()) return s;
  MotionFile m;
  m.positions = ToThirtyFps(pos, 1.0 / frame_time);
  return m;
}

absl::StatusOr<MotionFile> ReadMotionFile(const std::string& path) {
  if (path.size() >= 4 && (path.substr(path.size() - 4) == ".bvh" || path.substr(path.size() - 4) == ".BVH")) {
    absl::StatusOr<std::string> text = ReadText(path);
    if (!text.ok()) return text.status();
    absl::StatusOr<MotionFile> m = ParseBvh(*text);
    if (!m.ok()) return absl::InvalidArgumentError(absl::StrCat("'", path, "': ", m.status().message()));
    return m;
  }
  absl::StatusOr<std::string> text = ReadText(path);
  if (!text.ok()) return text.status();
  return MotionFromJson(*text, path);
}

absl::StatusOr<MotionFile> ParseMotionJson(const std::string& text) { return MotionFromJson(text, "motion"); }

absl::StatusOr<std::string> ReadTextFile(const std::string& path) { return ReadText(path); }

absl::StatusOr<MotionFile> ParseMotionText(const std::string& text, const std::string& name) {
  const size_t first = text.find_first_not_of(" \t\r\n");
  if (first != std::string::npos && text.compare(first, 9, "HIERARCHY") == 0) {
    absl::StatusOr<MotionFile> m = ParseBvh(text);
    if (!m.ok()) return absl::InvalidArgumentError(absl::StrCat("'", name, "': ", m.status().message()));
    return m;
  }
  return MotionFromJson(text, name);
}

absl::StatusOr<std::vector<TrajectoryPoint>> ReadTrajectoryFile(const std::string& path) {
  absl::StatusOr<std::string> text = ReadText(path);
  if (!text.ok()) return text.status();
  return ParseTrajectoryJson(*text, path);
}

absl::StatusOr<std::vector<TrajectoryPoint>> ParseTrajectoryJson(const std::string& text, const std::string& path) {
  absl::StatusOr<nlohmann::json> doc = ParseJson(text, path);
  if (!doc.ok()) return doc.status();
  const nlohmann::json& d = *doc;
  if (!IsFormat(d, "dance-trajectory/v1") || !d.contains("points") ||
      !d["points"].is_array()) {
    return absl::InvalidArgumentError(absl::StrCat("'", path, "': not a dance-trajectory/v1 file with \"points\""));
  }
  std::vector<TrajectoryPoint> out;
  for (const nlohmann::json& p : d["points"]) {
    if (!p.is_object() || !p.contains("t") || !p["t"].is_number() || !p.contains("x") || !p["x"].is_number() ||
        !p.contains("z") || !p["z"].is_number() || (p.contains("facing") && !p["facing"].is_number())) {
      return absl::InvalidArgumentError(absl::StrCat("'", path, "': point ", out.size(),
                                                     " needs numbers t, x, z (and optionally facing)"));
    }
    TrajectoryPoint& q = out.emplace_back();
    q.t_s = p["t"].get<double>();
    q.x = p["x"].get<float>();
    q.z = p["z"].get<float>();
    if (p.contains("facing")) q.facing = p["facing"].get<float>();
  }
  if (out.size() < 2) return absl::InvalidArgumentError(absl::StrCat("'", path, "': a path needs >= 2 points"));
  Controls check;
  check.trajectory = out;
  if (absl::Status s = ValidateControls(check); !s.ok()) {
    return absl::InvalidArgumentError(absl::StrCat("'", path, "': ", s.message()));
  }
  return out;
}

absl::StatusOr<std::vector<JointMask>> ReadMaskFile(const std::string& path, const MotionFile& dance) {
  absl::StatusOr<std::string> text = ReadText(path);
  if (!text.ok()) return text.status();
  return ParseMaskJson(*text, dance, path);
}

absl::StatusOr<std::vector<JointMask>> ParseMaskJson(const std::string& text, const MotionFile& dance,
                                                     const std::string& path) {
  absl::StatusOr<std::vector<MaskSpan>> spans = ParseMaskSpansJson(text, path);
  if (!spans.ok()) return spans.status();
  return MaskFromSpans(*spans, dance, path);
}

absl::StatusOr<std::vector<MaskSpan>> ParseMaskSpansJson(const std::string& text, const std::string& path) {
  absl::StatusOr<nlohmann::json> doc = ParseJson(text, path);
  if (!doc.ok()) return doc.status();
  const nlohmann::json& d = *doc;
  if (!IsFormat(d, "dance-mask/v1") || !d.contains("known") ||
      !d["known"].is_array()) {
    return absl::InvalidArgumentError(absl::StrCat("'", path, "': not a dance-mask/v1 file with \"known\""));
  }
  std::vector<MaskSpan> spans;
  for (size_t i = 0; i < d["known"].size(); ++i) {
    const nlohmann::json& k = d["known"][i];
    if (!k.is_object() || !k.contains("start_s") || !k["start_s"].is_number() || !k.contains("end_s") ||
        !k["end_s"].is_number() || !k.contains("joints") || !k["joints"].is_array()) {
      return absl::InvalidArgumentError(absl::StrCat("'", path, "': known[", i,
                                                     "] needs start_s, end_s and a joints list"));
    }
    MaskSpan& span = spans.emplace_back();
    span.start_s = k["start_s"].get<double>();
    span.end_s = k["end_s"].get<double>();
    for (const nlohmann::json& name : k["joints"]) {
      if (!name.is_string()) return absl::InvalidArgumentError(absl::StrCat("'", path, "': a joint is not a name"));
      span.joints.push_back(name.get<std::string>());
    }
  }
  return spans;
}

absl::StatusOr<std::vector<JointMask>> MaskFromSpans(const std::vector<MaskSpan>& spans, const MotionFile& dance,
                                                     const std::string& path) {
  std::vector<JointMask> mask(dance.positions.size(), 0);
  // Times are on the dance's own timeline (its audio_offset_s, not rounded to the frame grid).
  const double begin_s = dance.offset_s, end_s = dance.offset_s + dance.positions.size() / kFps;
  for (size_t i = 0; i < spans.size(); ++i) {
    const double a = spans[i].start_s, b = spans[i].end_s;
    if (!(a < b) || a < begin_s - 1e-6 || b > end_s + 1e-6) {
      return absl::InvalidArgumentError(absl::StrCat("'", path, "': known[", i, "] [", a, ", ", b,
                                                     ") s is empty or outside the dance's [", begin_s, ", ", end_s,
                                                     ") s"));
    }
    JointMask bits = 0;
    for (const std::string& n : spans[i].joints) {
      if (n == "all") {
        bits = kAllJoints;
      } else if (n == "upper") {
        bits |= UpperMask();
      } else if (n == "lower") {
        bits |= LowerMask();
      } else {
        int found = -1;
        for (int j = 0; j < kNumJoints; ++j) {
          if (n == kSmplNames[j]) found = j;
        }
        if (found < 0) return absl::InvalidArgumentError(absl::StrCat("'", path, "': unknown joint '", n, "'"));
        bits |= JointMask{1} << found;
      }
    }
    for (size_t f = 0; f < mask.size(); ++f) {
      const double t = dance.offset_s + static_cast<double>(f) / kFps;
      if (t >= a - 1e-9 && t < b - 1e-9) mask[f] |= bits;
    }
  }
  return mask;
}

}  // namespace dance::engine
