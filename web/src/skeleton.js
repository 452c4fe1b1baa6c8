// The 24-joint SMPL skeleton the engine streams, and forward kinematics over it.
//
// The server sends the skeleton in its `info` message (joint_names, parents, rest_offsets); the constants
// here are the fallback when a server omits them, and they match ../shared/data/skeleton/smpl24_skeleton.json
// (SMPL neutral rest offsets, metres, Y up, the body facing +Z, its left side at +X).
//
// Conventions (docs/model.md, docs/protocol.md):
//   positions: 24 x (x, y, z) global, metres.
//   rotations: 24 x (w, x, y, z) LOCAL rotations: the rotation of joint j, composed down the tree, turns the
//   rest offsets of j's children into their posed directions (the BVH convention).

import * as THREE from 'three';

export const kNumJoints = 24;

export const kDefaultJointNames = [
  'pelvis', 'left_hip', 'right_hip', 'spine1', 'left_knee', 'right_knee', 'spine2', 'left_ankle',
  'right_ankle', 'spine3', 'left_foot', 'right_foot', 'neck', 'left_collar', 'right_collar', 'head',
  'left_shoulder', 'right_shoulder', 'left_elbow', 'right_elbow', 'left_wrist', 'right_wrist', 'left_hand',
  'right_hand',
];

export const kDefaultParents = [
  -1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21,
];

export const kDefaultRestOffsets = [
  [0.0, 0.0, 0.0], [0.05858, -0.08228, -0.01766], [-0.06031, -0.09051, -0.01354],
  [0.00444, 0.1244, -0.03839], [0.04345, -0.38647, 0.00804], [-0.04326, -0.38369, -0.00484],
  [0.00449, 0.13796, 0.02682], [-0.01479, -0.42687, -0.03743], [0.01906, -0.42005, -0.03456],
  [-0.00226, 0.05603, 0.00286], [0.04105, -0.06029, 0.12204], [-0.03484, -0.06211, 0.13032],
  [-0.01339, 0.21164, -0.03347], [0.0717, 0.114, -0.0189], [-0.08295, 0.11247, -0.02371],
  [0.01011, 0.08894, 0.05041], [0.12292, 0.04521, -0.01905], [-0.11323, 0.04685, -0.00847],
  [0.25533, -0.01565, -0.02295], [-0.26013, -0.01437, -0.03127], [0.26571, 0.0127, -0.00737],
  [-0.26911, 0.00679, -0.00603], [0.08669, -0.01064, -0.01559], [-0.08875, -0.00865, -0.01011],
];

// Upper-body joints (Bailando's split, docs/model.md): drawn in the upper colour.
export const kUpperJoints = new Set([3, 6, 9, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22, 23]);

/**
 * A skeleton description: names, parents and rest offsets (each offset relative to the parent).
 * Built from a server `info` message, falling back to the SMPL defaults for missing fields.
 */
export class Skeleton {
  constructor(info = {}) {
    const ok = (a, n) => Array.isArray(a) && a.length === n;
    this.jointNames = ok(info.joint_names, kNumJoints) ? info.joint_names.slice() : kDefaultJointNames.slice();
    this.parents = ok(info.parents, kNumJoints) ? info.parents.slice() : kDefaultParents.slice();
    let offsets = kDefaultRestOffsets;
    if (ok(info.rest_offsets, kNumJoints)) offsets = info.rest_offsets;
    else if (ok(info.rest_offsets, kNumJoints * 3)) {
      offsets = [];
      for (let j = 0; j < kNumJoints; ++j) offsets.push(info.rest_offsets.slice(3 * j, 3 * j + 3));
    }
    this.restOffsets = offsets.map((o) => [Number(o[0]), Number(o[1]), Number(o[2])]);
    this.children = this.parents.map(() => []);
    this.parents.forEach((p, j) => { if (p >= 0) this.children[p].push(j); });
  }

  /** Joints without children (they get an "End Site" in BVH). */
  leaves() {
    return this.children.map((c, j) => (c.length === 0 ? j : -1)).filter((j) => j >= 0);
  }
}

/**
 * Forward kinematics: global positions from the root position and local rotations.
 * @param {Skeleton} skeleton
 * @param {ArrayLike<number>} rootPosition  3 floats, metres
 * @param {ArrayLike<number>} rotations  96 floats, (w, x, y, z) per joint, local
 * @param {Float32Array} out  72 floats, written
 * @returns {Float32Array} out
 */
export function forwardKinematics(skeleton, rootPosition, rotations, out = new Float32Array(72)) {
  const global = [];
  const v = new THREE.Vector3();
  for (let j = 0; j < kNumJoints; ++j) {
    const local = new THREE.Quaternion(rotations[4 * j + 1], rotations[4 * j + 2], rotations[4 * j + 3],
                                       rotations[4 * j]);
    const p = skeleton.parents[j];
    if (p < 0) {
      global.push(local);
      out[0] = rootPosition[0]; out[1] = rootPosition[1]; out[2] = rootPosition[2];
      continue;
    }
    global.push(global[p].clone().multiply(local));
    v.fromArray(skeleton.restOffsets[j]).applyQuaternion(global[p]);
    out[3 * j] = out[3 * p] + v.x;
    out[3 * j + 1] = out[3 * p + 1] + v.y;
    out[3 * j + 2] = out[3 * p + 2] + v.z;
  }
  return out;
}
