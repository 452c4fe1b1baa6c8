// The humanoid bones of the SMPL skeleton (the same map as client/export/humanoid.h).

/** SMPL joint name -> VRM humanBone name (the 22 bones SMPL has). */
export const kSmplToVrm = {
  pelvis: 'hips', left_hip: 'leftUpperLeg', right_hip: 'rightUpperLeg', spine1: 'spine',
  left_knee: 'leftLowerLeg', right_knee: 'rightLowerLeg', spine2: 'chest', left_ankle: 'leftFoot',
  right_ankle: 'rightFoot', spine3: 'upperChest', left_foot: 'leftToes', right_foot: 'rightToes', neck: 'neck',
  left_collar: 'leftShoulder', right_collar: 'rightShoulder', head: 'head', left_shoulder: 'leftUpperArm',
  right_shoulder: 'rightUpperArm', left_elbow: 'leftLowerArm', right_elbow: 'rightLowerArm',
  left_wrist: 'leftHand', right_wrist: 'rightHand',
};
