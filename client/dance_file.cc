#include "client/dance_file.h"

#include <cmath>
#include <fstream>
#include <sstream>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "client/export/gltf_writer.h"

namespace dance::client {
namespace {

constexpr double kRadToDeg = 180.0 / M_PI;
constexpr double kMetresToBvh = 100.0;  // centimetres

absl::Status WriteText(const std::string& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary);
  if (!out) return absl::PermissionDeniedError(absl::StrCat("cannot write ", path));
  out << text;
  out.close();
  if (!out) return absl::DataLossError(absl::StrCat("write failed: ", path));
  return absl::OkStatus();
}

}  // namespace

nlohmann::json DanceToJson(const dance::v1::SessionInfo& info, const std::vector<dance::v1::PoseFrame>& frames,
                           uint64_t seed, const std::vector<double>& beat_times_s) {
  using nlohmann::json;
  const auto& sk = info.skeleton();
  json rest = json::array();
  for (int j = 0; j + 2 < sk.rest_offsets_size(); j += 3) {
    rest.push_back({sk.rest_offsets(j), sk.rest_offsets(j + 1), sk.rest_offsets(j + 2)});
  }
  json positions = json::array(), rotations = json::array(), upper = json::array(), lower = json::array();
  for (const auto& f : frames) {
    json p = json::array();
    for (int j = 0; j + 2 < f.positions_size(); j += 3) p.push_back({f.positions(j), f.positions(j + 1), f.positions(j + 2)});
    positions.push_back(std::move(p));
    if (f.rotations_size() > 0) {
      json r = json::array();
      for (int j = 0; j + 3 < f.rotations_size(); j += 4) {
        r.push_back({f.rotations(j), f.rotations(j + 1), f.rotations(j + 2), f.rotations(j + 3)});
      }
      rotations.push_back(std::move(r));
    }
    upper.push_back(f.upper_code());
    lower.push_back(f.lower_code());
  }
  json out = {{"format", "dance-motion/v1"},
              {"fps", info.fps() > 0 ? info.fps() : 30.0},
              {"units", "m"},
              {"up_axis", "y"},
              {"joint_names", std::vector<std::string>(sk.joint_names().begin(), sk.joint_names().end())},
              {"parents", std::vector<int>(sk.parents().begin(), sk.parents().end())},
              {"rest_offsets", rest},
              {"positions", positions},
              {"audio_offset_s", frames.empty() ? 0.0 : frames.front().time_ms() / 1000.0},
              {"first_frame_index", frames.empty() ? 0 : frames.front().index()},
              {"codes", {{"upper", upper}, {"lower", lower}}},
              {"model_id", info.model_id()},
              {"session_id", info.session_id()},
              {"seed", seed}};
  if (!rotations.empty()) out["rotations"] = rotations;
  if (!beat_times_s.empty()) out["beat_times_s"] = beat_times_s;
  return out;
}

absl::Status WriteDanceJson(const std::string& path, const dance::v1::SessionInfo& info,
                            const std::vector<dance::v1::PoseFrame>& frames, uint64_t seed,
                            const std::vector<double>& beat_times_s) {
  return WriteText(path, DanceToJson(info, frames, seed, beat_times_s).dump());
}

std::vector<double> BeatTimesOf(const std::vector<dance::v1::Event>& events) {
  std::vector<double> out;
  for (const dance::v1::Event& e : events) {
    if (e.kind() == dance::v1::Event::KIND_BEAT) out.push_back(std::round(e.time_ms()) / 1000.0);
  }
  return out;
}

std::array<double, 3> QuaternionToEulerZXY(double w, double x, double y, double z) {
  // Rotation matrix of q, then R = Rz(a) Rx(b) Ry(c): m21 = sin(b), m01 = -sin(a)cos(b), m11 = cos(a)cos(b),
  // m20 = -cos(b)sin(c), m22 = cos(b)cos(c).
  const double m01 = 2 * (x * y - w * z), m11 = 1 - 2 * (x * x + z * z);
  const double m21 = 2 * (y * z + w * x), m20 = 2 * (x * z - w * y), m22 = 1 - 2 * (x * x + y * y);
  const double b = std::asin(std::clamp(m21, -1.0, 1.0));
  double a, c;
  if (std::abs(m21) < 0.999999) {
    a = std::atan2(-m01, m11);
    c = std::atan2(-m20, m22);
  } else {  // gimbal lock: put everything into Z
    const double m00 = 1 - 2 * (y * y + z * z), m10 = 2 * (x * y + w * z);
    a = std::atan2(m10, m00);
    c = 0.0;
  }
  return {a * kRadToDeg, b * kRadToDeg, c * kRadToDeg};
}

std::string DanceToBvh(const dance::v1::SessionInfo& info, const std::vector<dance::v1::PoseFrame>& frames) {
  const auto& sk = info.skeleton();
  const int n = sk.parents_size();
  std::vector<std::vector<int>> children(n);
  for (int j = 1; j < n; ++j) children[sk.parents(j)].push_back(j);
  std::string out = "HIERARCHY\n";
  std::vector<int> order;  // joints in the order their channels appear
  auto offset = [&](int j) {
    return absl::StrFormat("%.4f %.4f %.4f", sk.rest_offsets(3 * j) * kMetresToBvh,
                           sk.rest_offsets(3 * j + 1) * kMetresToBvh, sk.rest_offsets(3 * j + 2) * kMetresToBvh);
  };
  auto emit = [&](auto&& self, int j, int depth) -> void {
    const std::string pad(2 * depth, ' ');
    absl::StrAppend(&out, pad, j == 0 ? "ROOT " : "JOINT ", sk.joint_names(j), "\n", pad, "{\n", pad,
                    "  OFFSET ", j == 0 ? std::string("0 0 0") : offset(j), "\n", pad, "  CHANNELS ",
                    j == 0 ? "6 Xposition Yposition Zposition Zrotation Xrotation Yrotation"
                           : "3 Zrotation Xrotation Yrotation",
                    "\n");
    order.push_back(j);
    for (int c : children[j]) self(self, c, depth + 1);
    if (children[j].empty()) absl::StrAppend(&out, pad, "  End Site\n", pad, "  {\n", pad, "    OFFSET 0 0 0\n", pad, "  }\n");
    absl::StrAppend(&out, pad, "}\n");
  };
  if (n > 0) emit(emit, 0, 0);
  absl::StrAppend(&out, "MOTION\nFrames: ", frames.size(), "\nFrame Time: ",
                  absl::StrFormat("%.6f", 1.0 / (info.fps() > 0 ? info.fps() : 30.0)), "\n");
  for (const auto& f : frames) {
    std::string line = absl::StrFormat("%.4f %.4f %.4f", f.positions(0) * kMetresToBvh,
                                       f.positions(1) * kMetresToBvh, f.positions(2) * kMetresToBvh);
    for (int j : order) {
      std::array<double, 3> e{0, 0, 0};
      if (f.rotations_size() >= 4 * (j + 1)) {
        e = QuaternionToEulerZXY(f.rotations(4 * j), f.rotations(4 * j + 1), f.rotations(4 * j + 2),
                                 f.rotations(4 * j + 3));
      }
      absl::StrAppend(&line, absl::StrFormat(" %.4f %.4f %.4f", e[0], e[1], e[2]));
    }
    absl::StrAppend(&out, line, "\n");
  }
  return out;
}

absl::Status WriteBvh(const std::string& path, const dance::v1::SessionInfo& info,
                      const std::vector<dance::v1::PoseFrame>& frames) {
  return WriteText(path, DanceToBvh(info, frames));
}

MotionClip ClipFromStream(const dance::v1::SessionInfo& info, const std::vector<dance::v1::PoseFrame>& frames) {
  const auto& sk = info.skeleton();
  MotionClip clip;
  clip.fps = info.fps() > 0 ? info.fps() : 30.0;
  clip.joint_names.assign(sk.joint_names().begin(), sk.joint_names().end());
  clip.parents.assign(sk.parents().begin(), sk.parents().end());
  const int n = sk.parents_size();
  for (int j = 0; j < n && 3 * j + 2 < sk.rest_offsets_size(); ++j) {
    clip.rest_offsets.push_back({sk.rest_offsets(3 * j), sk.rest_offsets(3 * j + 1), sk.rest_offsets(3 * j + 2)});
  }
  for (const auto& f : frames) {
    clip.root_positions.push_back(f.positions_size() >= 3 ? Vec3{f.positions(0), f.positions(1), f.positions(2)}
                                                          : Vec3{0, 0, 0});
    for (int j = 0; j < n; ++j) {
      if (f.rotations_size() >= 4 * (j + 1)) {
        clip.rotations.push_back(
            {f.rotations(4 * j), f.rotations(4 * j + 1), f.rotations(4 * j + 2), f.rotations(4 * j + 3)});
      } else {
        clip.rotations.push_back({1, 0, 0, 0});
      }
    }
  }
  return clip;
}

absl::Status WriteDanceFile(const std::string& path, const dance::v1::SessionInfo& info,
                            const std::vector<dance::v1::PoseFrame>& frames, uint64_t seed,
                            const std::vector<double>& beat_times_s) {
  const std::string lower = absl::AsciiStrToLower(path);
  if (absl::EndsWith(lower, ".bvh")) return WriteBvh(path, info, frames);
  GltfKind kind;
  if (GltfKindForPath(path, &kind)) return WriteMotionFile(path, ClipFromStream(info, frames));
  return WriteDanceJson(path, info, frames, seed, beat_times_s);
}

absl::Status ReadDanceJson(const std::string& path, dance::v1::SessionInfo* info,
                           std::vector<dance::v1::PoseFrame>* frames) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError(absl::StrCat("cannot read ", path));
  std::stringstream text;
  text << in.rdbuf();
  const nlohmann::json doc = nlohmann::json::parse(text.str(), nullptr, /*allow_exceptions=*/false);
  auto bad = [&](const std::string& why) { return absl::InvalidArgumentError(absl::StrCat(path, ": ", why)); };
  if (!doc.is_object() || doc.value("format", "") != "dance-motion/v1") return bad("not a dance-motion/v1 file");
  for (const char* key : {"joint_names", "parents", "rest_offsets", "positions"}) {
    if (!doc.contains(key) || !doc[key].is_array()) return bad(absl::StrCat("no '", key, "' array"));
  }
  const size_t n = doc["parents"].size();
  if (doc["joint_names"].size() != n || doc["rest_offsets"].size() != n) {
    return bad("joint_names, parents and rest_offsets differ in length");
  }
  info->Clear();
  frames->clear();
  info->set_fps(doc.contains("fps") && doc["fps"].is_number() ? doc["fps"].get<double>() : 30.0);
  if (doc.contains("model_id") && doc["model_id"].is_string()) info->set_model_id(doc["model_id"].get<std::string>());
  if (doc.contains("session_id") && doc["session_id"].is_string()) {
    info->set_session_id(doc["session_id"].get<std::string>());
  }
  auto* sk = info->mutable_skeleton();
  for (size_t j = 0; j < n; ++j) {
    const auto& name = doc["joint_names"][j];
    const auto& parent = doc["parents"][j];
    const auto& off = doc["rest_offsets"][j];
    if (!name.is_string() || !parent.is_number_integer() || !off.is_array() || off.size() != 3) {
      return bad(absl::StrCat("bad skeleton entry ", j));
    }
    sk->add_joint_names(name.get<std::string>());
    sk->add_parents(parent.get<int>());
    for (const auto& v : off) {
      if (!v.is_number()) return bad(absl::StrCat("bad rest offset ", j));
      sk->add_rest_offsets(v.get<float>());
    }
  }
  const auto& positions = doc["positions"];
  const bool has_rot = doc.contains("rotations") && doc["rotations"].is_array();
  if (has_rot && doc["rotations"].size() != positions.size()) return bad("rotations and positions differ in length");
  const double offset_s = doc.contains("audio_offset_s") && doc["audio_offset_s"].is_number()
                              ? doc["audio_offset_s"].get<double>()
                              : 0.0;
  const int64_t first = doc.contains("first_frame_index") && doc["first_frame_index"].is_number_integer()
                            ? doc["first_frame_index"].get<int64_t>()
                            : 0;
  for (size_t t = 0; t < positions.size(); ++t) {
    dance::v1::PoseFrame f;
    f.set_index(first + static_cast<int64_t>(t));
    f.set_time_ms((offset_s + t / info->fps()) * 1000.0);
    if (!positions[t].is_array() || positions[t].size() != n) return bad(absl::StrCat("bad positions[", t, "]"));
    for (const auto& p : positions[t]) {
      if (!p.is_array() || p.size() != 3) return bad(absl::StrCat("bad positions[", t, "]"));
      for (const auto& v : p) {
        if (!v.is_number()) return bad(absl::StrCat("bad positions[", t, "]"));
        f.add_positions(v.get<float>());
      }
    }
    if (has_rot) {
      const auto& r = doc["rotations"][t];
      if (!r.is_array() || r.size() != n) return bad(absl::StrCat("bad rotations[", t, "]"));
      for (const auto& q : r) {
        if (!q.is_array() || q.size() != 4) return bad(absl::StrCat("bad rotations[", t, "]"));
        for (const auto& v : q) {
          if (!v.is_number()) return bad(absl::StrCat("bad rotations[", t, "]"));
          f.add_rotations(v.get<float>());
        }
      }
    }
    frames->push_back(std::move(f));
  }
  return absl::OkStatus();
}

}  // namespace dance::client
