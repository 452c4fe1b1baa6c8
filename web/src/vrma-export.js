// VRM Animation (.vrma) from a recording: the page's counterpart of client/export/gltf_writer.cc (same
// layout, so both read the same way): a binary glTF 2.0 with one node per joint under a node "dance"
// (named as the joints, rest translation = rest offset, the root's rest translation putting the rest
// pose's lowest joint on the floor, identity rest rotations), the VRMC_vrm_animation extension (spec 1.0)
// mapping the 22 humanoid bones, and one animation "dance": per joint a rotation channel (the local
// rotations as glTF's x, y, z, w) and the root's translation (its world position), LINEAR, times from 0 at
// the recording's fps. glTF and VRM 1.0 share the stream's frame (Y up, facing +Z, left at +X).
//
// Usage:
//   const bytes = motionToVrma(recorder.toMotion());     // Uint8Array; throws without rotations
//   downloadBytes(bytes, 'dance.vrma', 'model/gltf-binary');

import { kSmplToVrm } from './vrm-bones.js';

const kFloat = 5126;

/** @param {object} motion  dance-motion/v1 with parents, rest_offsets and rotations */
export function motionToVrma(motion) {
  const { parents, rest_offsets: rest, positions, rotations, joint_names: names } = motion;
  if (!rotations || !rotations.length) throw new Error('VRMA needs a recording with rotations');
  const n = parents.length;
  const frames = rotations.length;
  const fps = motion.fps || 30;
  // Rest positions (root at the origin) and the floor.
  const restPos = [[0, 0, 0]];
  for (let j = 1; j < n; ++j) restPos.push(restPos[parents[j]].map((v, k) => v + rest[j][k]));
  const lowest = Math.min(0, ...restPos.map((p) => p[1]));

  const chunks = [];
  let binLength = 0;
  const bufferViews = [];
  const accessors = [];
  const add = (floats, type, bounds = false) => {
    const data = new Float32Array(floats);
    bufferViews.push({ buffer: 0, byteOffset: binLength, byteLength: data.byteLength });
    chunks.push(data);
    binLength += data.byteLength;  // floats keep 4-byte alignment
    const acc = { bufferView: bufferViews.length - 1, componentType: kFloat, count: data.length / (type === 'SCALAR' ? 1 : Number(type.slice(3))), type };
    if (bounds) { acc.min = [Math.min(...data)]; acc.max = [Math.max(...data)]; }
    accessors.push(acc);
    return accessors.length - 1;
  };

  const nodes = [{ name: 'dance', children: [1] }];
  for (let j = 0; j < n; ++j) {
    const node = { name: names[j], translation: j === 0 ? [0, -lowest, 0] : rest[j].slice() };
    const children = [];
    for (let c = j + 1; c < n; ++c) if (parents[c] === j) children.push(1 + c);
    if (children.length) node.children = children;
    nodes.push(node);
  }
  const time = add(Array.from({ length: frames }, (_, t) => t / fps), 'SCALAR', true);
  const samplers = [{ input: time, output: add(positions.flatMap((p) => p[0]), 'VEC3'), interpolation: 'LINEAR' }];
  const channels = [{ sampler: 0, target: { node: 1, path: 'translation' } }];
  for (let j = 0; j < n; ++j) {
    const q = rotations.flatMap((r) => [r[j][1], r[j][2], r[j][3], r[j][0]]);
    samplers.push({ input: time, output: add(q, 'VEC4'), interpolation: 'LINEAR' });
    channels.push({ sampler: samplers.length - 1, target: { node: 1 + j, path: 'rotation' } });
  }
  const humanBones = {};
  names.forEach((name, j) => { if (kSmplToVrm[name]) humanBones[kSmplToVrm[name]] = { node: 1 + j }; });
  if (!humanBones.hips) throw new Error("VRMA needs a skeleton with a 'pelvis'");
  const doc = {
    asset: { version: '2.0', generator: 'dance-web recorder (web/src/vrma-export.js)', extras: { fps, frames } },
    scene: 0,
    scenes: [{ name: 'dance', nodes: [0] }],
    nodes,
    animations: [{ name: 'dance', samplers, channels }],
    accessors,
    bufferViews,
    buffers: [{ byteLength: binLength }],
    extensionsUsed: ['VRMC_vrm_animation'],
    extensions: { VRMC_vrm_animation: { specVersion: '1.0', humanoid: { humanBones } } },
  };
  let json = new TextEncoder().encode(JSON.stringify(doc));
  const jsonPadded = new Uint8Array(Math.ceil(json.length / 4) * 4).fill(0x20);
  jsonPadded.set(json);
  json = jsonPadded;
  const total = 12 + 8 + json.length + 8 + binLength;
  const out = new Uint8Array(total);
  const view = new DataView(out.buffer);
  view.setUint32(0, 0x46546c67, true);  // "glTF"
  view.setUint32(4, 2, true);
  view.setUint32(8, total, true);
  view.setUint32(12, json.length, true);
  view.setUint32(16, 0x4e4f534a, true);  // "JSON"
  out.set(json, 20);
  let at = 20 + json.length;
  view.setUint32(at, binLength, true);
  view.setUint32(at + 4, 0x004e4942, true);  // "BIN\0"
  at += 8;
  for (const c of chunks) {
    out.set(new Uint8Array(c.buffer), at);
    at += c.byteLength;
  }
  return out;
}

/** Saves bytes as a download. */
export function downloadBytes(bytes, filename, type = 'application/octet-stream') {
  const url = URL.createObjectURL(new Blob([bytes], { type }));
  const a = document.createElement('a');
  a.href = url;
  a.download = filename;
  document.body.appendChild(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(url), 1000);
}
