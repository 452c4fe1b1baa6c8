// Unit tests of the page's recorder: dance-motion/v1 JSON and BVH whose rotations reproduce the positions.
import assert from 'node:assert/strict';
import test from 'node:test';
import { Recorder } from '../../web/src/recorder.js';
import { Skeleton, forwardKinematics } from '../../web/src/skeleton.js';

// The same module instance web/src imports as 'three'.
import * as THREE from '../../web/node_modules/three/build/three.module.js';

function randomFrame(index, rng) {
  const rotations = [];
  for (let j = 0; j < 24; ++j) {
    const q = new THREE.Quaternion().setFromEuler(new THREE.Euler(rng() - 0.5, 2 * rng() - 1, rng() - 0.5));
    rotations.push(q.w, q.x, q.y, q.z);
  }
  const skeleton = new Skeleton();
  const positions = forwardKinematics(skeleton, [rng(), 0.9 + 0.1 * rng(), rng()], rotations);
  return { type: 'frame', index, time_ms: (index * 1000) / 30, positions: Array.from(positions), rotations,
           upper_code: index, lower_code: 2 * index };
}

function lcg(seed) {
  let s = seed;
  return () => ((s = (s * 1103515245 + 12345) % 2147483648) / 2147483648);
}

/** Parses the BVH written by Recorder.toBvh and rebuilds global positions by forward kinematics. */
function bvhPositions(text) {
  const lines = text.split('\n');
  const joints = [];
  const stack = [];
  let pendingEnd = false;
  for (const line of lines) {
    const t = line.trim();
    if (t === 'MOTION') break;
    const m = /^(ROOT|JOINT) (\S+)/.exec(t);
    if (m) { joints.push({ name: m[2], parent: stack.length ? stack[stack.length - 1] : -1, offset: null }); continue; }
    if (t === 'End Site') { pendingEnd = true; continue; }
    if (t === '{') { if (!pendingEnd) stack.push(joints.length - 1); continue; }
    if (t === '}') { if (pendingEnd) pendingEnd = false; else stack.pop(); continue; }
    if (t.startsWith('OFFSET') && !pendingEnd) joints[joints.length - 1].offset = t.split(/\s+/).slice(1).map(Number);
  }
  const motion = text.split('MOTION\n')[1].trim().split('\n').slice(2);
  return motion.map((row) => {
    const v = row.split(' ').map(Number);
    let c = 3;
    const globalQ = [];
    const pos = [];
    joints.forEach((j, i) => {
      const [z, x, y] = v.slice(c, c + 3).map((d) => (d * Math.PI) / 180);
      c += 3;
      const local = new THREE.Quaternion().setFromEuler(new THREE.Euler(x, y, z, 'ZXY'));
      if (j.parent < 0) {
        globalQ.push(local);
        pos.push(new THREE.Vector3(v[0], v[1], v[2]));
      } else {
        globalQ.push(globalQ[j.parent].clone().multiply(local));
        pos.push(new THREE.Vector3(...j.offset).applyQuaternion(globalQ[j.parent]).add(pos[j.parent]));
      }
    });
    return { names: joints.map((j) => j.name), pos };
  });
}

test('Recorder writes dance-motion/v1 with gaps filled at a constant rate', () => {
  const rng = lcg(3);
  const r = new Recorder();
  r.push(randomFrame(0, rng));  // before start: ignored
  r.start({ skeleton: new Skeleton(), fps: 30, sessionId: 's-1', latencyMs: 0 });
  for (const i of [10, 11, 12, 14, 15]) r.push(randomFrame(i, rng));
  r.push(randomFrame(12, rng));  // repeated: ignored
  const m = JSON.parse(r.toJson());
  assert.equal(m.format, 'dance-motion/v1');
  assert.equal(m.fps, 30);
  assert.deepEqual(m.frame_indices, [10, 11, 12, 13, 14, 15]);
  assert.equal(m.positions.length, 6);
  assert.deepEqual(m.positions[3], m.positions[2]);
  assert.ok(Math.abs(m.audio_offset_s - 1 / 3) < 1e-9);
  assert.equal(m.rotations[0][0].length, 4);
  assert.equal(m.session_id, 's-1');
});

test('BVH rotations and offsets reproduce the recorded joint positions', () => {
  const rng = lcg(11);
  const r = new Recorder();
  const skeleton = new Skeleton();
  r.start({ skeleton, fps: 30 });
  const frames = [];
  for (let i = 0; i < 5; ++i) { frames.push(randomFrame(i, rng)); r.push(frames[i]); }
  const parsed = bvhPositions(r.toBvh());
  assert.equal(parsed.length, 5);
  parsed.forEach((p, f) => {
    p.names.forEach((name, k) => {
      const j = skeleton.jointNames.indexOf(name);
      const want = frames[f].positions.slice(3 * j, 3 * j + 3);
      const err = Math.hypot(p.pos[k].x - want[0], p.pos[k].y - want[1], p.pos[k].z - want[2]);
      assert.ok(err < 1e-3, `frame ${f} joint ${name}: ${err} m`);
    });
  });
});

test('BVH export refuses an empty recording', () => {
  const r = new Recorder();
  r.start({ skeleton: new Skeleton() });
  assert.throws(() => r.toBvh(), /nothing recorded/);
});
