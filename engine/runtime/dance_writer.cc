#include "engine/runtime/dance_writer.h"

#include <cmath>
#include <fstream>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"

namespace dance::engine {
namespace {

constexpr double kFps = 30.0;

absl::Status WriteText(const std::string& path, const std::string& text) {
  std::ofstream f(path, std::ios::trunc);
  if (!f) return absl::PermissionDeniedError(absl::StrCat("cannot write '", path, "'"));
  f << text;
  f.close();
  if (!f) return absl::DataLossError(absl::StrCat("error writing '", path, "'"));
  return absl::OkStatus();
}

float Round6(float v) { return std::round(v * 1e6f) / 1e6f; }

// Z, X, Y Euler angles in degrees with R = Rz(a) Rx(b) Ry(c) (the BVH channel order written below).
Eigen::Vector3f ZxyDegrees(const Eigen::Quaternionf& q) {
  const Eigen::Matrix3f m = q.normalized().toRotationMatrix();
  // R = Rz Rx Ry: m(2,1) = sin(b); m(0,1) = -sin(a) cos(b); m(1,1) = cos(a) cos(b);
  // m(2,0) = -cos(b) sin(c); m(2,2) = cos(b) cos(c).
  const float b = std::asin(std::clamp(m(2, 1), -1.0f, 1.0f));
  float a, c;
  if (std::abs(m(2, 1)) < 0.999999f) {
    a = std::atan2(-m(0, 1), m(1, 1));
    c = std::atan2(-m(2, 0), m(2, 2));
  } else {  // gimbal lock: put everything in a
    a = std::atan2(m(1, 0), m(0, 0));
    c = 0.0f;
  }
  constexpr float kDeg = 180.0f / static_cast<float>(M_PI);
  return Eigen::Vector3f(a * kDeg, b * kDeg, c * kDeg);
}

void BvhJoint(const Skeleton& s, int j, int depth, std::string* out) {
  const std::string pad(2 * depth, ' ');
  const Eigen::Vector3f& o = s.offsets[j];
  if (j == 0) {
    absl::StrAppend(out, "ROOT ", s.joint_names[j], "\n{\n");
    absl::StrAppend(out, pad, "  OFFSET 0.000000 0.000000 0.000000\n");
    absl::StrAppend(out, pad, "  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation\n");
  } else {
    absl::StrAppend(out, pad, "JOINT ", s.joint_names[j], "\n", pad, "{\n");
    absl::StrAppend(out, pad, absl::StrFormat("  OFFSET %.6f %.6f %.6f\n", o.x(), o.y(), o.z()));
    absl::StrAppend(out, pad, "  CHANNELS 3 Zrotation Xrotation Yrotation\n");
  }
  if (s.children[j].empty()) {
    // End Site: half the leaf's own bone, continuing its direction (Blender needs a non-zero tail).
    const Eigen::Vector3f e = 0.5f * o;
    absl::StrAppend(out, pad, "  End Site\n", pad, "  {\n",
                    pad, absl::StrFormat("    OFFSET %.6f %.6f %.6f\n", e.x(), e.y(), e.z()), pad, "  }\n");
  }
  for (int c : s.children[j]) BvhJoint(s, c, depth + 1, out);
  absl::StrAppend(out, pad, "}\n");
}

// Depth-first joint order of the hierarchy (the MOTION channel order).
void DepthFirst(const Skeleton& s, int j, std::vector<int>* order) {
  order->push_back(j);
  for (int c : s.children[j]) DepthFirst(s, c, order);
}

}  // namespace

nlohmann::json DanceJson(const Skeleton& skeleton, const std::vector<PoseFrame>& frames, const DanceInfo& info) {
  nlohmann::json doc = {{"format", "dance-motion/v1"},
                        {"fps", kFps},
                        {"units", "m"},
                        {"up_axis", "y"},
                        {"joint_names", skeleton.joint_names}};
  nlohmann::json parents = nlohmann::json::array(), offsets = nlohmann::json::array();
  for (int j = 0; j < kNumJoints; ++j) {
    parents.push_back(skeleton.parents[j]);
    offsets.push_back({skeleton.offsets[j].x(), skeleton.offsets[j].y(), skeleton.offsets[j].z()});
  }
  doc["parents"] = parents;
  doc["rest_offsets"] = offsets;
  nlohmann::json positions = nlohmann::json::array(), rotations = nlohmann::json::array();
  nlohmann::json upper = nlohmann::json::array(), lower = nlohmann::json::array();
  for (const PoseFrame& f : frames) {
    nlohmann::json p = nlohmann::json::array(), r = nlohmann::json::array();
    for (int j = 0; j < kNumJoints; ++j) {
      p.push_back({Round6(f.positions[j].x()), Round6(f.positions[j].y()), Round6(f.positions[j].z())});
      const Eigen::Quaternionf& q = f.rotations[j];
      r.push_back({Round6(q.w()), Round6(q.x()), Round6(q.y()), Round6(q.z())});
    }
    positions.push_back(std::move(p));
    rotations.push_back(std::move(r));
    upper.push_back(f.upper_code);
    lower.push_back(f.lower_code);
  }
  doc["positions"] = std::move(positions);
  doc["rotations"] = std::move(rotations);
  doc["upper_codes"] = std::move(upper);
  doc["lower_codes"] = std::move(lower);
  doc["frame_index0"] = frames.empty() ? 0 : frames.front().index;
  doc["audio_offset_s"] = frames.empty() ? 0.0 : frames.front().time_s;
  doc["model_id"] = info.model_id;
  doc["seed"] = info.seed;
  for (const auto& [key, value] : info.extra.items()) doc[key] = value;
  return doc;
}

absl::Status WriteDanceJson(const std::string& path, const Skeleton& skeleton,
                            const std::vector<PoseFrame>& frames, const DanceInfo& info) {
  return WriteText(path, DanceJson(skeleton, frames, info).dump());
}

std::string BvhText(const Skeleton& skeleton, const std::vector<PoseFrame>& frames) {
  std::string out = "HIERARCHY\n";
  BvhJoint(skeleton, 0, 0, &out);
  std::vector<int> order;
  DepthFirst(skeleton, 0, &order);
  absl::StrAppend(&out, "MOTION\nFrames: ", frames.size(), "\n",
                  absl::StrFormat("Frame Time: %.8f\n", 1.0 / kFps));
  for (const PoseFrame& f : frames) {
    const Eigen::Vector3f& root = f.positions[0];
    absl::StrAppend(&out, absl::StrFormat("%.6f %.6f %.6f", root.x(), root.y(), root.z()));
    for (int j : order) {
      const Eigen::Vector3f e = ZxyDegrees(f.rotations[j]);
      absl::StrAppend(&out, absl::StrFormat(" %.4f %.4f %.4f", e.x(), e.y(), e.z()));
    }
    out.push_back('\n');
  }
  return out;
}

absl::Status WriteBvh(const std::string& path, const Skeleton& skeleton, const std::vector<PoseFrame>& frames) {
  return WriteText(path, BvhText(skeleton, frames));
}

}  // namespace dance::engine
