// Test fixture: the 24-joint SMPL skeleton (names as the engine's, offsets rounded from the skeleton file)
// and random dances on it, as MotionClips.
#ifndef DANCE_TESTS_CLIENT_SMPL_TEST_CLIP_H_
#define DANCE_TESTS_CLIENT_SMPL_TEST_CLIP_H_

#include <cmath>
#include <random>

#include "client/export/motion_clip.h"

namespace dance::client::testing {

inline MotionClip SmplSkeleton() {
  MotionClip c;
  c.joint_names = {"pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2", "left_ankle", "right_ankle", "spine3", "left_foot", "right_foot", "neck", "left_collar", "right_collar", "head", "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_hand", "right_hand"};
  c.parents = {-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21};
  c.rest_offsets = {
      {0.0000f, 0.0000f, 0.0000f},
      {0.0586f, -0.0823f, -0.0177f},
      {-0.0603f, -0.0905f, -0.0135f},
      {0.0044f, 0.1244f, -0.0384f},
      {0.0435f, -0.3865f, 0.0080f},
      {-0.0433f, -0.3837f, -0.0048f},
      {0.0045f, 0.1380f, 0.0268f},
      {-0.0148f, -0.4269f, -0.0374f},
      {0.0191f, -0.4200f, -0.0346f},
      {-0.0023f, 0.0560f, 0.0029f},
      {0.0411f, -0.0603f, 0.1220f},
      {-0.0348f, -0.0621f, 0.1303f},
      {-0.0134f, 0.2116f, -0.0335f},
      {0.0717f, 0.1140f, -0.0189f},
      {-0.0830f, 0.1125f, -0.0237f},
      {0.0101f, 0.0889f, 0.0504f},
      {0.1229f, 0.0452f, -0.0190f},
      {-0.1132f, 0.0469f, -0.0085f},
      {0.2553f, -0.0156f, -0.0229f},
      {-0.2601f, -0.0144f, -0.0313f},
      {0.2657f, 0.0127f, -0.0074f},
      {-0.2691f, 0.0068f, -0.0060f},
      {0.0867f, -0.0106f, -0.0156f},
      {-0.0888f, -0.0087f, -0.0101f}};
  return c;
}

// `frames` frames of smoothly varying random local rotations (leaves keep the identity, as the engine's)
// and a wandering root, at 30 fps.
inline MotionClip RandomDance(int frames, unsigned seed) {
  MotionClip c = SmplSkeleton();
  std::mt19937 gen(seed);
  std::normal_distribution<float> n(0.0f, 1.0f);
  const int j_count = c.num_joints();
  std::vector<std::array<float, 6>> phase(j_count);
  for (auto& p : phase) {
    for (float& v : p) v = n(gen);
  }
  std::vector<bool> leaf(j_count, true);
  for (int j = 1; j < j_count; ++j) leaf[c.parents[j]] = false;
  for (int t = 0; t < frames; ++t) {
    const float s = t / 30.0f;
    c.root_positions.push_back({0.3f * std::sin(s), 0.9f + 0.05f * std::sin(3 * s), 0.2f * std::cos(2 * s)});
    for (int j = 0; j < j_count; ++j) {
      if (leaf[j] && j != 0) {
        c.rotations.push_back({1, 0, 0, 0});
        continue;
      }
      const auto& p = phase[j];
      Quat q{1.0f, 0.4f * std::sin(2 * s + p[0]) * p[1], 0.4f * std::sin(3 * s + p[2]) * p[3],
             0.4f * std::sin(s + p[4]) * p[5]};
      const float len = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
      for (float& v : q) v /= len;
      c.rotations.push_back(q);
    }
  }
  return c;
}

}  // namespace dance::client::testing

#endif  // DANCE_TESTS_CLIENT_SMPL_TEST_CLIP_H_
