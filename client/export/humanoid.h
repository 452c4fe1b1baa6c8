// The humanoid bones of the SMPL skeleton: which Unity HumanBodyBones bone (the names VMC sends) and which
// VRM humanBone (the names VRM and VRM Animation use: the same, lower camel case) each joint drives.
//
//   pelvis hips · spine1 spine · spine2 chest · spine3 upperChest · neck neck · head head
//   left/right_hip UpperLeg · knee LowerLeg · ankle Foot · foot Toes
//   left/right_collar Shoulder · shoulder UpperArm · elbow LowerArm · wrist Hand
// The SMPL hand joints (left_hand, right_hand: the end of the palm, always the identity rotation) have no
// humanoid bone. "left" is the body's own left in both conventions.
//
// Usage:
//   std::vector<int> joint = HumanoidJointIndices(clip.joint_names);   // -1 where a name is missing
//   for (size_t b = 0; b < kHumanoidBones.size(); ++b) Send(kHumanoidBones[b].unity_name, joint[b]);
//
// Thread safety: constant data and pure functions.
#ifndef DANCE_CLIENT_EXPORT_HUMANOID_H_
#define DANCE_CLIENT_EXPORT_HUMANOID_H_

#include <array>
#include <string>
#include <vector>

namespace dance::client {

struct HumanoidBone {
  const char* smpl_name;   // the skeleton's joint name (engine/vq/skeleton.cc)
  const char* unity_name;  // UnityEngine.HumanBodyBones
  const char* vrm_name;    // VRMC_vrm / VRMC_vrm_animation humanBones key
};

// In parent-before-child order.
inline constexpr std::array<HumanoidBone, 22> kHumanoidBones = {{
    {"pelvis", "Hips", "hips"},
    {"left_hip", "LeftUpperLeg", "leftUpperLeg"},
    {"right_hip", "RightUpperLeg", "rightUpperLeg"},
    {"spine1", "Spine", "spine"},
    {"left_knee", "LeftLowerLeg", "leftLowerLeg"},
    {"right_knee", "RightLowerLeg", "rightLowerLeg"},
    {"spine2", "Chest", "chest"},
    {"left_ankle", "LeftFoot", "leftFoot"},
    {"right_ankle", "RightFoot", "rightFoot"},
    {"spine3", "UpperChest", "upperChest"},
    {"left_foot", "LeftToes", "leftToes"},
    {"right_foot", "RightToes", "rightToes"},
    {"neck", "Neck", "neck"},
    {"left_collar", "LeftShoulder", "leftShoulder"},
    {"right_collar", "RightShoulder", "rightShoulder"},
    {"head", "Head", "head"},
    {"left_shoulder", "LeftUpperArm", "leftUpperArm"},
    {"right_shoulder", "RightUpperArm", "rightUpperArm"},
    {"left_elbow", "LeftLowerArm", "leftLowerArm"},
    {"right_elbow", "RightLowerArm", "rightLowerArm"},
    {"left_wrist", "LeftHand", "leftHand"},
    {"right_wrist", "RightHand", "rightHand"},
}};

// For each entry of kHumanoidBones, the index of its joint in `joint_names`, or -1 if absent.
std::vector<int> HumanoidJointIndices(const std::vector<std::string>& joint_names);

}  // namespace dance::client

#endif  // DANCE_CLIENT_EXPORT_HUMANOID_H_
