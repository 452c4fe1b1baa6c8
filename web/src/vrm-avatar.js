// A VRM avatar (VRM 0.x or 1.0, loaded by @pixiv/three-vrm) driven by the stream's local joint rotations.
//
// Each SMPL joint with a humanoid bone (kSmplToVrm, the same map as client/export/humanoid.h) sets the
// local rotation of that bone of the avatar's *normalised* rig, whose rest pose is a T-pose with identity
// local rotations facing +Z: the frame of docs/rotations.md. SMPL's rest pose is close to that T-pose but
// not equal: its arms slope down 3-8 degrees and its legs stand 2-8 degrees apart, where the T-pose's are
// level and straight. So by default (retarget) each limb bone (kAim) gets a constant correction C_j, the
// shortest arc taking the avatar's rest bone onto SMPL's: the avatar's global rotation is R_j = G_j C_j and
// its local one L'_j = C_parent^-1 L_j C_j, which points the avatar's arms and legs exactly along the
// dance's (the twist about the bone is the minimal one). The spine, neck, head, collars and feet are left
// as they are: there the rest poses differ by anatomy, not by pose (SMPL's head joint sits 30 degrees
// forward of its neck, its collar bones rise 22 degrees to the shoulder joint, where a rig's neck and
// shoulder bones are upright and level in the same upright, relaxed stance), and aiming them would bow
// the avatar's head and shrug its shoulders. retarget = false sends every rotation unchanged. VRM
// 0.x avatars are turned to face +Z by VRMUtils.rotateVRM0, so their normalised rig is mirrored in X and
// Z: rotations (x, y, z, w) -> (-x, y, -z, w), positions (x, y, z) -> (-x, y, -z), as three-vrm-animation
// does for .vrma. The hips move with the pelvis, scaled by the avatar's hips height over SMPL's.
//
// Usage:
//   const avatar = await VrmAvatar.load(arrayBufferOrUrl, skeleton);
//   scene.add(avatar.group);
//   every display frame: avatar.setPose(positions, rotations); avatar.update(dtSeconds);
//   avatar.playVrma(arrayBuffer) plays a VRM Animation (.vrma) instead of the stream (for checking files).
// Owns its Three.js objects; dispose() when replacing it. Not thread-safe.

import * as THREE from 'three';
import { GLTFLoader } from 'three/examples/jsm/loaders/GLTFLoader.js';
import { VRMLoaderPlugin, VRMUtils } from '@pixiv/three-vrm';
import { VRMAnimationLoaderPlugin, createVRMAnimationClip } from '@pixiv/three-vrm-animation';
import { forwardKinematics, kNumJoints } from './skeleton.js';
import { kSmplToVrm } from './vrm-bones.js';

export { kSmplToVrm };

/** The limb bones the rest correction aims, each at its child. */
const kAim = {
  leftUpperArm: 'leftLowerArm', leftLowerArm: 'leftHand', rightUpperArm: 'rightLowerArm',
  rightLowerArm: 'rightHand', leftUpperLeg: 'leftLowerLeg', leftLowerLeg: 'leftFoot',
  rightUpperLeg: 'rightLowerLeg', rightLowerLeg: 'rightFoot',
};

function loader() {
  const l = new GLTFLoader();
  l.register((parser) => new VRMLoaderPlugin(parser));
  l.register((parser) => new VRMAnimationLoaderPlugin(parser));
  return l;
}

/** The height of the skeleton's root above its lowest joint in the rest pose (m). */
function restRootHeight(skeleton) {
  const identity = new Float32Array(4 * kNumJoints);
  for (let j = 0; j < kNumJoints; ++j) identity[4 * j] = 1;
  const p = forwardKinematics(skeleton, [0, 0, 0], identity);
  let minY = 0;
  for (let j = 0; j < kNumJoints; ++j) minY = Math.min(minY, p[3 * j + 1]);
  return -minY;
}

export class VrmAvatar {
  /**
   * @param {ArrayBuffer|string} source  the .vrm file's bytes or its URL
   * @param {import('./skeleton.js').Skeleton} skeleton  the stream's skeleton (joint names, rest offsets)
   */
  static async load(source, skeleton, { retarget = true } = {}) {
    const l = loader();
    const gltf = typeof source === 'string' ? await l.loadAsync(source) : await l.parseAsync(source, '');
    const vrm = gltf.userData.vrm;
    if (!vrm) throw new Error('not a VRM file (no VRM or VRMC_vrm extension)');
    return new VrmAvatar(vrm, skeleton, { retarget });
  }

  constructor(vrm, skeleton, { retarget = true } = {}) {
    this.vrm = vrm;
    this.retarget = retarget;
    this.v0 = vrm.meta?.metaVersion === '0';
    if (this.v0) VRMUtils.rotateVRM0(vrm);
    VRMUtils.removeUnnecessaryVertices(vrm.scene);
    vrm.scene.traverse((o) => {
      o.frustumCulled = false;  // skinned meshes move away from their rest bounds
      if (o.isMesh) o.castShadow = true;
    });
    this.group = new THREE.Group();
    this.group.name = 'vrm-avatar';
    this.group.add(vrm.scene);
    this.name = vrm.meta?.name || vrm.meta?.title || 'VRM';
    this.pelvis = new THREE.Vector3();
    this.mixer = null;
    this.setSkeleton(skeleton);
  }

  /** Binds the SMPL joints to this avatar's bones (call again when the stream's skeleton changes). */
  setSkeleton(skeleton) {
    this.skeleton = skeleton;
    this.bones = [];  // {joint, name, node, c (C_j), cParentInv (C_parent^-1)}
    const rest = this.vrm.humanoid.normalizedRestPose;
    const m = this.v0 ? -1 : 1;
    const correction = new Map();  // joint -> C_j (our frame)
    for (let j = 0; j < skeleton.jointNames.length; ++j) {
      const name = kSmplToVrm[skeleton.jointNames[j]];
      const node = name ? this.vrm.humanoid.getNormalizedBoneNode(name) : null;
      if (!node) continue;
      const c = new THREE.Quaternion();
      const aim = kAim[name];
      const child = aim ? skeleton.jointNames.findIndex((n) => kSmplToVrm[n] === aim) : -1;
      if (this.retarget && child >= 0 && skeleton.parents[child] === j && rest[aim]?.position) {
        // Rest bone directions in our frame: the avatar's child offset (identity rest rotations), SMPL's.
        const p = rest[aim].position;
        const avatarDir = new THREE.Vector3(m * p[0], p[1], m * p[2]).normalize();
        const smplDir = new THREE.Vector3(...skeleton.restOffsets[child]).normalize();
        if (avatarDir.lengthSq() > 0 && smplDir.lengthSq() > 0) c.setFromUnitVectors(avatarDir, smplDir);
      }
      correction.set(j, c);
      this.bones.push({ joint: j, name, node, c });
    }
    for (const b of this.bones) {
      const parent = correction.get(skeleton.parents[b.joint]);
      b.cParentInv = parent ? parent.clone().invert() : new THREE.Quaternion();
    }
    this._q = new THREE.Quaternion();
    this.hips = this.vrm.humanoid.getNormalizedBoneNode('hips');
    const avatarHips = this.vrm.humanoid.normalizedRestPose.hips?.position?.[1] ?? 1;
    this.hipsScale = avatarHips / Math.max(0.1, restRootHeight(skeleton));
  }

  /** The humanoid bones this avatar drives (names). */
  get driven() { return this.bones.map((b) => b.name); }

  /**
   * Poses the avatar from a frame.
   * @param {Float32Array} positions  72 floats (the root's are used)
   * @param {Float32Array|null} rotations  96 floats, local (w, x, y, z)
   */
  setPose(positions, rotations) {
    if (this.mixer || !rotations) return;
    const m = this.v0 ? -1 : 1;
    const q = this._q;
    for (const { joint, node, c, cParentInv } of this.bones) {
      const o = 4 * joint;
      q.set(rotations[o + 1], rotations[o + 2], rotations[o + 3], rotations[o]);  // L_j, our frame
      q.premultiply(cParentInv).multiply(c);                                      // C_parent^-1 L_j C_j
      node.quaternion.set(m * q.x, q.y, m * q.z, q.w);
    }
    const s = this.hipsScale;
    this.hips.position.set(m * positions[0] * s, positions[1] * s, m * positions[2] * s);
    this.pelvis.set(positions[0] * s, positions[1] * s, positions[2] * s);
  }

  /** Plays a VRM Animation (.vrma bytes) on the avatar, looping; returns {duration, tracks}. */
  async playVrma(bytes) {
    const gltf = await loader().parseAsync(bytes, '');
    const animation = gltf.userData.vrmAnimations?.[0];
    if (!animation) throw new Error('not a VRM Animation file (no VRMC_vrm_animation)');
    const clip = createVRMAnimationClip(animation, this.vrm);
    this.mixer = new THREE.AnimationMixer(this.vrm.scene);
    this.mixer.clipAction(clip).play();
    this.vrmaDuration = clip.duration;
    return { duration: clip.duration, tracks: clip.tracks.length };
  }

  /** Stops a .vrma and returns to the stream. */
  stopVrma() {
    this.mixer?.stopAllAction();
    this.mixer = null;
  }

  /** Seeks a playing .vrma to `seconds` (for tests and scrubbing), clamped to the clip. */
  seekVrma(seconds) {
    // The loop wraps at the clip's duration (a float32 keyframe time): seeking to the last frame's time in
    // double precision can land on or past it and show frame 0, so the end is held a microsecond early.
    const end = this.vrmaDuration ?? 0;
    this.mixer?.setTime(Math.max(0, Math.min(seconds, end - 1e-6)));
    this.vrm.update(0);
    this.hips.getWorldPosition(this.pelvis);
  }

  /** Local rotation (x, y, z, w) of a humanoid bone of the normalised rig, in the stream's frame. */
  boneRotation(name) {
    const q = this.vrm.humanoid.getNormalizedBoneNode(name)?.quaternion;
    if (!q) return null;
    const m = this.v0 ? -1 : 1;
    return [m * q.x, q.y, m * q.z, q.w];
  }

  update(dt) {
    if (this.mixer) {
      this.mixer.update(dt);
      this.hips.getWorldPosition(this.pelvis);
    }
    this.vrm.update(dt);
  }

  /** World-space points of the driven bones (for framing and screenshot regions). */
  jointPoints() {
    this.group.updateMatrixWorld(true);
    return this.bones.map(({ name }) => this.vrm.humanoid.getRawBoneNode(name)?.getWorldPosition(new THREE.Vector3()))
      .filter(Boolean);
  }

  dispose() {
    this.group.removeFromParent();
    VRMUtils.deepDispose(this.vrm.scene);
  }
}
