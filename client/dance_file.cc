#include "client/dance_file.h"

#include <cmath>
#include <fstream>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"

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
                           uint64_t seed) {
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
  return out;
}

absl::Status WriteDanceJson(const std::string& path, const dance::v1::SessionInfo& info,
                            const std::vector<dance::v1::PoseFrame>& frames, uint64_t seed) {
  return WriteText(path, DanceToJson(info, frames, seed).dump());
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

}  // namespace dance::client
