// Records the received frames of a stream and saves them as dance-motion/v1 JSON or BVH.
//
// dance-motion/v1 (docs/model.md): {"format": "dance-motion/v1", "fps", "units": "m", "up_axis": "y",
// "joint_names", "positions": [T][24][3], "audio_offset_s", ...} plus the optional keys "parents",
// "rest_offsets", "rotations" [T][24][4] (w, x, y, z, local), "codes" {"upper", "lower"}, "frame_indices",
// "session_id", "model_latency_ms", "source".
// BVH: the skeleton's rest offsets as the hierarchy, the root with 6 channels (position + rotation), every
// other joint with 3 rotation channels in Z X Y order (degrees), metres as the unit, one line per frame.
// Frames missing from the recording (a gap in `index`) are filled by repeating the previous frame, so the
// files keep a constant frame rate.

import * as THREE from 'three';

export class Recorder {
  constructor() {
    this.frames = [];
    this.recording = false;
    this.meta = {};
  }

  /** Starts a new recording; `meta` = {skeleton, fps, sessionId, latencyMs, modelId}. */
  start(meta) {
    this.frames = [];
    this.meta = { ...meta };
    this.recording = true;
  }

  stop() { this.recording = false; }

  get length() { return this.frames.length; }

  /** Adds a protocol frame message while recording. */
  push(msg) {
    if (!this.recording) return;
    const last = this.frames[this.frames.length - 1];
    if (last && msg.index <= last.index) return;
    this.frames.push({
      index: msg.index,
      timeMs: msg.time_ms,
      positions: Array.from(msg.positions),
      rotations: Array.isArray(msg.rotations) ? Array.from(msg.rotations) : null,
      upper: msg.upper_code,
      lower: msg.lower_code,
    });
  }

  /** Frames on a constant-rate grid from the first recorded index to the last (gaps repeat a frame). */
  _dense() {
    const out = [];
    for (let i = 0; i < this.frames.length; ++i) {
      const f = this.frames[i];
      if (out.length) {
        const prev = out[out.length - 1];
        for (let k = prev.index + 1; k < f.index; ++k) out.push({ ...prev, index: k, filled: true });
      }
      out.push(f);
    }
    return out;
  }

  /** The recording as a dance-motion/v1 object. */
  toMotion() {
    const frames = this._dense();
    const sk = this.meta.skeleton;
    const fps = this.meta.fps || 30;
    const group = (flat, n) => {
      const rows = [];
      for (let j = 0; j < flat.length / n; ++j) rows.push(flat.slice(n * j, n * j + n).map(round6));
      return rows;
    };
    const motion = {
      format: 'dance-motion/v1',
      fps,
      units: 'm',
      up_axis: 'y',
      joint_names: sk.jointNames,
      parents: sk.parents,
      rest_offsets: sk.restOffsets,
      positions: frames.map((f) => group(f.positions, 3)),
      audio_offset_s: frames.length ? frames[0].timeMs / 1000 : 0,
      frame_indices: frames.map((f) => f.index),
      codes: { upper: frames.map((f) => f.upper), lower: frames.map((f) => f.lower) },
      source: 'dance-web recorder',
    };
    if (frames.length && frames.every((f) => f.rotations)) {
      motion.rotations = frames.map((f) => group(f.rotations, 4));
    }
    if (this.meta.sessionId !== undefined) motion.session_id = this.meta.sessionId;
    if (this.meta.latencyMs !== undefined) motion.model_latency_ms = this.meta.latencyMs;
    if (this.meta.modelId !== undefined) motion.model_id = this.meta.modelId;
    return motion;
  }

  toJson() { return JSON.stringify(this.toMotion()); }

  /** The recording as BVH text (needs rotations in the frames). */
  toBvh() {
    const frames = this._dense();
    const sk = this.meta.skeleton;
    const fps = this.meta.fps || 30;
    if (!frames.length) throw new Error('nothing recorded');
    if (!frames.every((f) => f.rotations)) throw new Error('the stream carries no rotations');
    const lines = ['HIERARCHY'];
    const order = [];  // joints in the order their channels appear
    const fmt = (v) => v.toFixed(6);
    const writeJoint = (j, depth) => {
      const pad = '  '.repeat(depth);
      const name = sk.jointNames[j].replace(/\s+/g, '_');
      const o = sk.parents[j] < 0 ? [0, 0, 0] : sk.restOffsets[j];
      lines.push(`${pad}${sk.parents[j] < 0 ? 'ROOT' : 'JOINT'} ${name}`, `${pad}{`);
      lines.push(`${pad}  OFFSET ${o.map(fmt).join(' ')}`);
      lines.push(sk.parents[j] < 0 ?
        `${pad}  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation` :
        `${pad}  CHANNELS 3 Zrotation Xrotation Yrotation`);
      order.push(j);
      if (sk.children[j].length === 0) {
        // End site: continue the bone's direction by a short segment.
        const len = Math.hypot(...o) || 1;
        const end = o.map((c) => (c / len) * 0.08);
        lines.push(`${pad}  End Site`, `${pad}  {`, `${pad}    OFFSET ${end.map(fmt).join(' ')}`, `${pad}  }`);
      }
      for (const c of sk.children[j]) writeJoint(c, depth + 1);
      lines.push(`${pad}}`);
    };
    for (let j = 0; j < sk.parents.length; ++j) if (sk.parents[j] < 0) writeJoint(j, 0);
    lines.push('MOTION', `Frames: ${frames.length}`, `Frame Time: ${(1 / fps).toFixed(8)}`);
    const q = new THREE.Quaternion();
    const e = new THREE.Euler();
    const deg = 180 / Math.PI;
    for (const f of frames) {
      const values = [];
      for (const j of order) {
        if (sk.parents[j] < 0) values.push(f.positions[3 * j], f.positions[3 * j + 1], f.positions[3 * j + 2]);
        const r = f.rotations;
        q.set(r[4 * j + 1], r[4 * j + 2], r[4 * j + 3], r[4 * j]).normalize();
        // BVH "Zrotation Xrotation Yrotation" = R = Rz * Rx * Ry, which is three.js's 'ZXY' order.
        e.setFromQuaternion(q, 'ZXY');
        values.push(e.z * deg, e.x * deg, e.y * deg);
      }
      lines.push(values.map((v) => v.toFixed(4)).join(' '));
    }
    return lines.join('\n') + '\n';
  }
}

function round6(v) { return Math.round(v * 1e6) / 1e6; }

/** Offers `text` to the user as a file download. */
export function downloadText(text, filename, type) {
  const url = URL.createObjectURL(new Blob([text], { type }));
  const a = document.createElement('a');
  a.href = url;
  a.download = filename;
  document.body.appendChild(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(url), 1000);
}
