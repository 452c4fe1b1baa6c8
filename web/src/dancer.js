// A clean capsule-body dancer on the 24-joint skeleton.
//
// Every bone (joint -> parent) is a capsule whose radius depends on the body part; the head is a sphere
// with a small visor that shows where the dancer faces. Left limbs are blue, right limbs orange, the trunk
// light grey, so left/right mistakes in the data are visible at a glance.
//
// Two ways to drive it (`setPose`):
//   'positions' (default): the 72 global joint positions of the frame (the engine projects them onto the
//                          canonical bone lengths, so capsules keep their length);
//   'rotations':           forward kinematics from the root position and the 24 local rotations over the
//                          skeleton's rest offsets (what a skinned avatar or a BVH player sees).
// Owns its Three.js objects; call dispose() when replacing it. Not thread-safe.

import * as THREE from 'three';
import { forwardKinematics, kNumJoints } from './skeleton.js';

// Capsule radius (m) of the bone ending at each joint (index = child joint); 0 = no capsule.
const kBoneRadius = [
  0, 0.075, 0.075, 0.095, 0.065, 0.065, 0.1, 0.05, 0.05, 0.11, 0.04, 0.04,
  0.05, 0.055, 0.055, 0.045, 0.05, 0.05, 0.042, 0.042, 0.035, 0.035, 0.03, 0.03,
];

const kColorLeft = 0x4fb3f0;
const kColorRight = 0xff8a5c;
const kColorTrunk = 0xdedfe4;

// SMPL order (the contract): odd-numbered limb joints are left, even ones right.
const kLeftJoints = new Set([1, 4, 7, 10, 13, 16, 18, 20, 22]);
const kRightJoints = new Set([2, 5, 8, 11, 14, 17, 19, 21, 23]);

function sideOf(joint) {
  if (kLeftJoints.has(joint)) return 'left';
  if (kRightJoints.has(joint)) return 'right';
  return 'trunk';
}

export class Dancer {
  /** @param {import('./skeleton.js').Skeleton} skeleton */
  constructor(skeleton) {
    this.skeleton = skeleton;
    this.group = new THREE.Group();
    this.group.name = 'dancer';
    this.mode = 'positions';
    this.positions = new Float32Array(kNumJoints * 3);
    const materials = {
      left: new THREE.MeshStandardMaterial({ color: kColorLeft, roughness: 0.45, metalness: 0.05 }),
      right: new THREE.MeshStandardMaterial({ color: kColorRight, roughness: 0.45, metalness: 0.05 }),
      trunk: new THREE.MeshStandardMaterial({ color: kColorTrunk, roughness: 0.5, metalness: 0.05 }),
    };
    this.materials = Object.values(materials);
    this.bones = [];
    for (let j = 0; j < kNumJoints; ++j) {
      const p = skeleton.parents[j];
      const radius = kBoneRadius[j];
      if (p < 0 || radius === 0) continue;
      const restLength = Math.max(1e-3, Math.hypot(...skeleton.restOffsets[j]));
      const geometry = new THREE.CapsuleGeometry(radius, Math.max(1e-3, restLength - radius), 6, 14);
      const side = sideOf(j);
      const mesh = new THREE.Mesh(geometry, materials[side]);
      mesh.castShadow = true;
      mesh.matrixAutoUpdate = false;
      this.group.add(mesh);
      this.bones.push({ joint: j, parent: p, mesh, restLength });
    }
    this.headIndex = skeleton.jointNames.indexOf('head');
    if (this.headIndex < 0) this.headIndex = 15;
    this.head = new THREE.Mesh(new THREE.SphereGeometry(0.105, 24, 16), materials.trunk);
    this.head.castShadow = true;
    this.visor = new THREE.Mesh(
      new THREE.BoxGeometry(0.13, 0.04, 0.05),
      new THREE.MeshStandardMaterial({ color: 0x20242c, roughness: 0.3 }));
    this.visor.position.set(0, 0.01, 0.09);
    this.head.add(this.visor);
    this.group.add(this.head);
    this.materials.push(this.visor.material);
    this.pelvis = new THREE.Vector3();
    this._a = new THREE.Vector3();
    this._b = new THREE.Vector3();
    this._dir = new THREE.Vector3();
    this._scale = new THREE.Vector3(1, 1, 1);
    this._up = new THREE.Vector3(0, 1, 0);
    this._q = new THREE.Quaternion();
  }

  /** 'positions' or 'rotations' (see the file comment). */
  setMode(mode) { this.mode = mode === 'rotations' ? 'rotations' : 'positions'; }

  /**
   * Poses the body.
   * @param {Float32Array} positions  72 floats, global joint positions (m)
   * @param {Float32Array|null} rotations  96 floats, local (w, x, y, z); used in 'rotations' mode
   */
  setPose(positions, rotations) {
    const P = this.positions;
    if (this.mode === 'rotations' && rotations) forwardKinematics(this.skeleton, positions, rotations, P);
    else P.set(positions);
    const a = this._a; const b = this._b; const dir = this._dir;
    for (const bone of this.bones) {
      a.fromArray(P, 3 * bone.parent);
      b.fromArray(P, 3 * bone.joint);
      dir.subVectors(b, a);
      const length = dir.length();
      if (length > 1e-6) dir.divideScalar(length); else dir.set(0, 1, 0);
      this._q.setFromUnitVectors(this._up, dir);
      this._scale.set(1, Math.max(0.2, length / bone.restLength), 1);
      bone.mesh.matrix.compose(a.add(b).multiplyScalar(0.5), this._q, this._scale);
      bone.mesh.matrixWorldNeedsUpdate = true;
    }
    // Head: at the head joint, facing the body's forward direction (across x up).
    const h = this.headIndex;
    this.head.position.set(P[3 * h], P[3 * h + 1] + 0.04, P[3 * h + 2]);
    const across = this._a.set(P[3 * 16] - P[3 * 17], 0, P[3 * 16 + 2] - P[3 * 17 + 2]);
    if (across.lengthSq() > 1e-8) {
      this.head.rotation.set(0, Math.atan2(-across.z, across.x), 0);
    }
    this.pelvis.set(P[0], P[1], P[2]);
  }

  /** Shows the skeleton's rest pose (all local rotations identity), standing on the floor. */
  showRestPose() {
    const identity = new Float32Array(96);
    for (let j = 0; j < kNumJoints; ++j) identity[4 * j] = 1;
    const p = forwardKinematics(this.skeleton, [0, 0, 0], identity);
    let minY = Infinity;
    for (let j = 0; j < kNumJoints; ++j) minY = Math.min(minY, p[3 * j + 1]);
    for (let j = 0; j < kNumJoints; ++j) p[3 * j + 1] += 0.03 - minY;
    const mode = this.mode;
    this.mode = 'positions';
    this.setPose(p, null);
    this.mode = mode;
  }

  /** World-space joint points (for framing and screenshot regions). */
  jointPoints() {
    const points = [];
    for (let j = 0; j < kNumJoints; ++j) points.push(new THREE.Vector3().fromArray(this.positions, 3 * j));
    return points;
  }

  dispose() {
    for (const bone of this.bones) bone.mesh.geometry.dispose();
    this.head.geometry.dispose();
    this.visor.geometry.dispose();
    for (const m of this.materials) m.dispose();
    this.group.removeFromParent();
  }
}
