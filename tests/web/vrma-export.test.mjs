// Unit tests of the page's VRMA export (web/src/vrma-export.js), read back like an importer: the GLB
// header and chunks, the VRMC_vrm_animation humanoid map, and forward kinematics of the nodes' rest
// translations with the animated rotations and root translation reproducing every recorded frame.
import assert from 'node:assert/strict';
import test from 'node:test';
import { Recorder } from '../../web/src/recorder.js';
import { Skeleton, forwardKinematics } from '../../web/src/skeleton.js';
import { motionToVrma } from '../../web/src/vrma-export.js';
import * as THREE from '../../web/node_modules/three/build/three.module.js';

function lcg(seed) {
  let s = seed;
  return () => ((s = (s * 1103515245 + 12345) % 2147483648) / 2147483648);
}

function recording(frames, { rotations = true } = {}) {
  const rng = lcg(7);
  const skeleton = new Skeleton();
  const r = new Recorder();
  r.start({ skeleton, fps: 30 });
  for (let i = 0; i < frames; ++i) {
    const rot = [];
    for (let j = 0; j < 24; ++j) {
      const q = new THREE.Quaternion().setFromEuler(new THREE.Euler(rng() - 0.5, 2 * rng() - 1, rng() - 0.5));
      rot.push(q.w, q.x, q.y, q.z);
    }
    const positions = forwardKinematics(skeleton, [rng(), 0.9 + 0.1 * rng(), rng()], rot);
    r.push({ index: i + (i > 5 ? 2 : 0), time_ms: i * 1000 / 30, positions: Array.from(positions),
             rotations: rotations ? rot : undefined, upper_code: 0, lower_code: 0 });
  }
  return r;
}

function parseGlb(bytes) {
  const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  assert.equal(view.getUint32(0, true), 0x46546c67);
  assert.equal(view.getUint32(4, true), 2);
  assert.equal(view.getUint32(8, true), bytes.byteLength);
  const jsonLength = view.getUint32(12, true);
  assert.equal(jsonLength % 4, 0);
  assert.equal(view.getUint32(16, true), 0x4e4f534a);
  const doc = JSON.parse(new TextDecoder().decode(bytes.subarray(20, 20 + jsonLength)));
  const binAt = 20 + jsonLength;
  const binLength = view.getUint32(binAt, true);
  assert.equal(view.getUint32(binAt + 4, true), 0x004e4942);
  assert.equal(binAt + 8 + binLength, bytes.byteLength);
  assert.equal(doc.buffers[0].byteLength, binLength);
  const bin = bytes.slice(binAt + 8, binAt + 8 + binLength);
  const floats = (accessor) => {
    const v = doc.bufferViews[doc.accessors[accessor].bufferView];
    return new Float32Array(bin.buffer, v.byteOffset, v.byteLength / 4);
  };
  return { doc, floats };
}

test('VRMA export maps the humanoid bones and its animation reproduces the recording', () => {
  const r = recording(12);
  const motion = r.toMotion();
  assert.equal(motion.positions.length, 14, 'the recorder fills the 2-frame gap');
  const { doc, floats } = parseGlb(motionToVrma(motion));
  assert.deepEqual(doc.extensionsUsed, ['VRMC_vrm_animation']);
  const ext = doc.extensions.VRMC_vrm_animation;
  assert.equal(ext.specVersion, '1.0');
  const bones = ext.humanoid.humanBones;
  assert.equal(Object.keys(bones).length, 22);
  assert.equal(doc.nodes[bones.hips.node].name, 'pelvis');
  assert.equal(doc.nodes[bones.leftUpperArm.node].name, 'left_shoulder');
  assert.equal(doc.nodes[bones.rightToes.node].name, 'right_foot');
  const anim = doc.animations[0];
  assert.equal(anim.channels.length, 25);
  const times = floats(anim.samplers[0].input);
  assert.equal(times.length, 14);
  assert.ok(Math.abs(times[1] - 1 / 30) < 1e-7);
  // FK over the nodes at each key, like an importer.
  const parent = {};
  doc.nodes.forEach((node, i) => (node.children || []).forEach((c) => { parent[c] = i; }));
  let worst = 0;
  for (let t = 0; t < times.length; ++t) {
    const rot = {}; const trans = {};
    for (const ch of anim.channels) {
      const out = floats(anim.samplers[ch.sampler].output);
      if (ch.target.path === 'rotation') rot[ch.target.node] = new THREE.Quaternion().fromArray(out, 4 * t);
      else trans[ch.target.node] = new THREE.Vector3().fromArray(out, 3 * t);
    }
    const g = { 0: new THREE.Quaternion() }; const p = { 0: new THREE.Vector3() };
    for (let n = 1; n <= 24; ++n) {
      const tr = trans[n] || new THREE.Vector3().fromArray(doc.nodes[n].translation);
      p[n] = tr.clone().applyQuaternion(g[parent[n]]).add(p[parent[n]]);
      g[n] = g[parent[n]].clone().multiply(rot[n]);
      const want = new THREE.Vector3(...motion.positions[t][n - 1]);
      worst = Math.max(worst, p[n].distanceTo(want));
    }
  }
  assert.ok(worst < 2e-5, `FK of the file is ${worst} m off the recording`);
});

test('VRMA export refuses a recording without rotations', () => {
  assert.throws(() => motionToVrma(recording(3, { rotations: false }).toMotion()), /rotations/);
});
