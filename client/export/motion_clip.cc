#include "client/export/motion_clip.h"

#include <cmath>

#include "absl/strings/str_cat.h"

namespace dance::client {

absl::Status ValidateClip(const MotionClip& clip) {
  const int j = clip.num_joints();
  if (j == 0) return absl::InvalidArgumentError("motion clip: no joints");
  if (static_cast<int>(clip.joint_names.size()) != j || static_cast<int>(clip.rest_offsets.size()) != j) {
    return absl::InvalidArgumentError(absl::StrCat("motion clip: ", j, " parents but ", clip.joint_names.size(),
                                                   " names and ", clip.rest_offsets.size(), " rest offsets"));
  }
  if (clip.parents[0] != -1) return absl::InvalidArgumentError("motion clip: joint 0 must be the root");
  for (int k = 1; k < j; ++k) {
    if (clip.parents[k] < 0 || clip.parents[k] >= k) {
      return absl::InvalidArgumentError(absl::StrCat("motion clip: joint ", k, " has parent ", clip.parents[k]));
    }
  }
  if (!(clip.fps > 0.0) || !std::isfinite(clip.fps)) return absl::InvalidArgumentError("motion clip: fps must be > 0");
  if (static_cast<int64_t>(clip.rotations.size()) != clip.num_frames() * j) {
    return absl::InvalidArgumentError(absl::StrCat("motion clip: ", clip.rotations.size(), " rotations for ",
                                                   clip.num_frames(), " frames of ", j, " joints"));
  }
  auto finite = [](const auto& a) {
    for (float v : a) {
      if (!std::isfinite(v)) return false;
    }
    return true;
  };
  for (const Vec3& v : clip.rest_offsets) {
    if (!finite(v)) return absl::InvalidArgumentError("motion clip: non-finite rest offset");
  }
  for (const Vec3& v : clip.root_positions) {
    if (!finite(v)) return absl::InvalidArgumentError("motion clip: non-finite root position");
  }
  for (const Quat& q : clip.rotations) {
    if (!finite(q)) return absl::InvalidArgumentError("motion clip: non-finite rotation");
  }
  return absl::OkStatus();
}

Quat QuatMul(const Quat& a, const Quat& b) {
  return {a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
          a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
          a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
          a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0]};
}

Quat QuatConj(const Quat& q) { return {q[0], -q[1], -q[2], -q[3]}; }

Vec3 QuatRotate(const Quat& q, const Vec3& v) {
  const Quat r = QuatMul(QuatMul(q, {0.0f, v[0], v[1], v[2]}), QuatConj(q));
  return {r[1], r[2], r[3]};
}

Quat QuatSlerp(const Quat& a, const Quat& b_in, float u) {
  Quat b = b_in;
  float d = a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3];
  if (d < 0.0f) {  // the shorter way round
    for (float& v : b) v = -v;
    d = -d;
  }
  float wa = 1.0f - u, wb = u;
  if (d < 0.9995f) {
    const float theta = std::acos(d), s = std::sin(theta);
    wa = std::sin((1.0f - u) * theta) / s;
    wb = std::sin(u * theta) / s;
  }
  Quat q{};
  float n = 0.0f;
  for (int k = 0; k < 4; ++k) {
    q[k] = wa * a[k] + wb * b[k];
    n += q[k] * q[k];
  }
  n = std::sqrt(n);
  for (float& v : q) v /= n;
  return q;
}

std::vector<Vec3> GlobalPositions(const MotionClip& clip, int64_t t) {
  const int n = clip.num_joints();
  std::vector<Quat> global(n);
  std::vector<Vec3> pos(n);
  for (int j = 0; j < n; ++j) {
    const Quat& local = clip.rotation(t, j);
    const int p = clip.parents[j];
    if (p < 0) {
      global[j] = local;
      pos[j] = clip.root_positions[t];
      continue;
    }
    global[j] = QuatMul(global[p], local);
    const Vec3 d = QuatRotate(global[p], clip.rest_offsets[j]);
    pos[j] = {pos[p][0] + d[0], pos[p][1] + d[1], pos[p][2] + d[2]};
  }
  return pos;
}

std::vector<Vec3> RestPositions(const MotionClip& clip) {
  std::vector<Vec3> pos(clip.num_joints());
  for (int j = 1; j < clip.num_joints(); ++j) {
    const Vec3& p = pos[clip.parents[j]];
    const Vec3& o = clip.rest_offsets[j];
    pos[j] = {p[0] + o[0], p[1] + o[1], p[2] + o[2]};
  }
  return pos;
}

}  // namespace dance::client
