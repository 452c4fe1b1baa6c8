#include "client/controls_request.h"

#include <fstream>
#include <sstream>
#include <vector>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "nlohmann/json.hpp"

namespace dance::client {
namespace {

using nlohmann::json;

absl::StatusOr<std::string> ReadFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError(absl::StrCat("cannot open '", path, "'"));
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

absl::StatusOr<json> ReadJson(const std::string& path, const char* format) {
  absl::StatusOr<std::string> text = ReadFile(path);
  if (!text.ok()) return text.status();
  json j = json::parse(*text, nullptr, /*allow_exceptions=*/false);
  if (j.is_discarded() || !j.is_object() || !j.contains("format") || j["format"] != format) {
    return absl::InvalidArgumentError(absl::StrCat("'", path, "': not a ", format, " file"));
  }
  return j;
}

bool IsNumber(const json& j, const char* key) { return j.contains(key) && j[key].is_number(); }

}  // namespace

absl::StatusOr<dance::v1::MotionControls> ControlsFromFiles(const ControlFiles& f) {
  dance::v1::MotionControls c;
  for (const auto& [path, motion] : {std::pair{&f.seed_motion, c.mutable_seed()},
                                     std::pair{&f.given_upper, c.mutable_given_upper()},
                                     std::pair{&f.given_lower, c.mutable_given_lower()},
                                     std::pair{&f.keyframes, c.mutable_keyframes()},
                                     std::pair{&f.inpaint, c.mutable_inpaint()}}) {
    if (path->empty()) continue;
    absl::StatusOr<std::string> text = ReadFile(*path);
    if (!text.ok()) return text.status();
    motion->set_file(*std::move(text));
  }
  if (f.inpaint.empty() != f.mask.empty()) return absl::InvalidArgumentError("--inpaint and --mask go together");
  if (!f.mask.empty()) {
    absl::StatusOr<json> j = ReadJson(f.mask, "dance-mask/v1");
    if (!j.ok()) return j.status();
    if (!j->contains("known") || !(*j)["known"].is_array()) {
      return absl::InvalidArgumentError(absl::StrCat("'", f.mask, "': no \"known\" list"));
    }
    for (const json& k : (*j)["known"]) {
      if (!k.is_object() || !IsNumber(k, "start_s") || !IsNumber(k, "end_s") || !k.contains("joints") ||
          !k["joints"].is_array()) {
        return absl::InvalidArgumentError(absl::StrCat("'", f.mask, "': a span needs start_s, end_s and joints"));
      }
      dance::v1::MaskSpan* span = c.add_inpaint_known();
      span->set_start_ms(k["start_s"].get<double>() * 1000.0);
      span->set_end_ms(k["end_s"].get<double>() * 1000.0);
      for (const json& n : k["joints"]) {
        if (!n.is_string()) return absl::InvalidArgumentError(absl::StrCat("'", f.mask, "': joints are names"));
        span->add_joints(n.get<std::string>());
      }
    }
  }
  if (!f.trajectory.empty()) {
    absl::StatusOr<json> j = ReadJson(f.trajectory, "dance-trajectory/v1");
    if (!j.ok()) return j.status();
    if (!j->contains("points") || !(*j)["points"].is_array()) {
      return absl::InvalidArgumentError(absl::StrCat("'", f.trajectory, "': no \"points\" list"));
    }
    for (const json& p : (*j)["points"]) {
      if (!p.is_object() || !IsNumber(p, "t") || !IsNumber(p, "x") || !IsNumber(p, "z") ||
          (p.contains("facing") && !p["facing"].is_number())) {
        return absl::InvalidArgumentError(absl::StrCat("'", f.trajectory, "': a point needs numbers t, x, z"));
      }
      dance::v1::PathPoint* q = c.add_trajectory();
      q->set_t_ms(p["t"].get<double>() * 1000.0);
      q->set_x(p["x"].get<float>());
      q->set_z(p["z"].get<float>());
      if (p.contains("facing")) q->set_facing(p["facing"].get<float>());
    }
  }
  return c;
}

absl::StatusOr<TimedControl> ParseSteerFlag(const std::string& text) {
  const std::vector<std::string> parts = absl::StrSplit(text, ':');
  double v[4];
  if (parts.size() != 4 || !absl::SimpleAtod(parts[0], &v[0]) || !absl::SimpleAtod(parts[1], &v[1]) ||
      !absl::SimpleAtod(parts[2], &v[2]) || !absl::SimpleAtod(parts[3], &v[3])) {
    return absl::InvalidArgumentError(absl::StrCat("--steer '", text, "': want AT:T:X:Z (seconds, metres)"));
  }
  TimedControl t;
  t.at_s = v[0];
  dance::v1::PathPoint* p = t.control.mutable_steer()->mutable_point();
  p->set_t_ms(v[1] * 1000.0);
  p->set_x(static_cast<float>(v[2]));
  p->set_z(static_cast<float>(v[3]));
  return t;
}

absl::StatusOr<TimedControl> ParseHandoverFlag(const std::string& text) {
  const size_t colon = text.find(':');
  TimedControl t;
  if (colon == std::string::npos || !absl::SimpleAtod(text.substr(0, colon), &t.at_s)) {
    return absl::InvalidArgumentError(absl::StrCat("--handover '", text, "': want AT:FILE"));
  }
  absl::StatusOr<std::string> clip = ReadFile(text.substr(colon + 1));
  if (!clip.ok()) return clip.status();
  t.control.mutable_controls()->mutable_seed()->set_file(*std::move(clip));
  return t;
}

}  // namespace dance::client
