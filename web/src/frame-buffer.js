// Received pose frames on the audio timeline, and their interpolation to any display time.
//
// Frames arrive at the stream's rate (30 fps); the display refreshes at its own rate (60, 120, 144 Hz).
// `sample(t)` returns the pose at audio time t (ms on the input timeline): positions are interpolated
// linearly and rotations by quaternion slerp between the two frames around t. Before the first frame it
// holds the first one, after the last frame it holds the last one and counts the request as an underrun
// (the stream fell behind the playout clock).
//
// Memory is bounded: frames older than `keepMs` before the last sampled time are dropped.
// Not thread-safe (there is one thread in a page anyway).

const kPositions = 72;
const kRotations = 96;

export class FrameBuffer {
  constructor({ keepMs = 3000 } = {}) {
    this.keepMs = keepMs;
    this.frames = [];  // {index, timeMs, positions: Float32Array(72), rotations: Float32Array(96)}
    this.underruns = 0;
    this.lastSampleMs = -Infinity;
    this.outPositions = new Float32Array(kPositions);
    this.outRotations = new Float32Array(kRotations);
  }

  clear() {
    this.frames = [];
    this.underruns = 0;
    this.lastSampleMs = -Infinity;
  }

  /** Adds a frame message (protocol `frame`); frames may arrive in order only, older ones are ignored. */
  push(msg) {
    const last = this.frames[this.frames.length - 1];
    if (last && msg.index <= last.index) return false;
    if (!Array.isArray(msg.positions) || msg.positions.length !== kPositions) return false;
    const rotations = Array.isArray(msg.rotations) && msg.rotations.length === kRotations ?
      Float32Array.from(msg.rotations) : null;
    this.frames.push({
      index: msg.index,
      timeMs: msg.time_ms,
      positions: Float32Array.from(msg.positions),
      rotations,
    });
    return true;
  }

  get length() { return this.frames.length; }
  get firstTimeMs() { return this.frames.length ? this.frames[0].timeMs : NaN; }
  get lastTimeMs() { return this.frames.length ? this.frames[this.frames.length - 1].timeMs : NaN; }

  /**
   * The pose at audio time `tMs`. Returns null when no frame has arrived yet, else
   * {positions, rotations (may be null), index, alpha}; the arrays are reused across calls.
   */
  sample(tMs) {
    const n = this.frames.length;
    if (n === 0) return null;
    this.lastSampleMs = tMs;
    // Drop what can no longer be needed.
    let drop = 0;
    while (drop < n - 2 && this.frames[drop + 1].timeMs < tMs - this.keepMs) ++drop;
    if (drop > 0) this.frames.splice(0, drop);

    const f = this.frames;
    if (tMs <= f[0].timeMs) return this._copy(f[0], f[0], 0);
    if (tMs >= f[f.length - 1].timeMs) {
      const lastFrame = f[f.length - 1];
      // A frame covers one frame period after its start: only beyond that is it an underrun.
      const period = f.length > 1 ? lastFrame.timeMs - f[f.length - 2].timeMs : 1000 / 30;
      if (tMs > lastFrame.timeMs + period) ++this.underruns;
      return this._copy(lastFrame, lastFrame, 0);
    }
    // Binary search for the last frame at or before t.
    let lo = 0;
    let hi = f.length - 1;
    while (hi - lo > 1) {
      const mid = (lo + hi) >> 1;
      if (f[mid].timeMs <= tMs) lo = mid; else hi = mid;
    }
    const a = f[lo];
    const b = f[hi];
    const span = b.timeMs - a.timeMs;
    const alpha = span > 0 ? (tMs - a.timeMs) / span : 0;
    return this._copy(a, b, alpha);
  }

  _copy(a, b, alpha) {
    const p = this.outPositions;
    for (let i = 0; i < kPositions; ++i) p[i] = a.positions[i] + (b.positions[i] - a.positions[i]) * alpha;
    let rotations = null;
    if (a.rotations && b.rotations) {
      rotations = this.outRotations;
      for (let j = 0; j < 24; ++j) slerpWxyz(a.rotations, b.rotations, 4 * j, alpha, rotations);
    }
    return { positions: p, rotations, index: alpha < 0.5 ? a.index : b.index, alpha };
  }
}

/** Slerp of unit quaternions stored (w, x, y, z) at offset `o` of `qa`, `qb`, written into `out`. */
export function slerpWxyz(qa, qb, o, t, out) {
  let bw = qb[o]; let bx = qb[o + 1]; let by = qb[o + 2]; let bz = qb[o + 3];
  const aw = qa[o]; const ax = qa[o + 1]; const ay = qa[o + 2]; const az = qa[o + 3];
  let cos = aw * bw + ax * bx + ay * by + az * bz;
  if (cos < 0) { cos = -cos; bw = -bw; bx = -bx; by = -by; bz = -bz; }  // shortest path
  let ka; let kb;
  if (cos > 0.9995) {  // nearly parallel: lerp, normalised below
    ka = 1 - t; kb = t;
  } else {
    const theta = Math.acos(cos);
    const s = Math.sin(theta);
    ka = Math.sin((1 - t) * theta) / s;
    kb = Math.sin(t * theta) / s;
  }
  let w = ka * aw + kb * bw; let x = ka * ax + kb * bx; let y = ka * ay + kb * by; let z = ka * az + kb * bz;
  const norm = Math.hypot(w, x, y, z) || 1;
  out[o] = w / norm; out[o + 1] = x / norm; out[o + 2] = y / norm; out[o + 3] = z / norm;
}
