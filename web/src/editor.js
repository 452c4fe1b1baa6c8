// The diffusion editor from the page (docs/web.md, "Edit a dance"; the server's /ws/edit, docs/protocol.md):
// one JSON request, the song file as one binary message, then the job's queue position and progress and
// the whole dance back, which the page plays with the song.
//
// Usage:
//   const request = { type: 'edit', style: 'waltz', seed: 1, steps: 0,
//                     controls: editControls('inpaint', recorder.toMotion(), 5, 10) };
//   const result = await runEdit(songBytes, request, (ev) => show(ev));   // ev: queued / progress
//   result.frames: [{index, time_ms, positions, rotations}], result.skeleton, result.compute_ms, ...

import { wsUrl } from './connection.js';

export const kEditModes = ['new', 'inpaint', 'upper', 'lower'];

/**
 * The controls of an edit of a recorded dance (dance-motion/v1 object), or null for a new dance:
 *   new:     the song only;
 *   inpaint: the recording kept except the audio times [fromS, toS), which are danced anew;
 *   upper:   the recording's legs and path kept, a new upper body;
 *   lower:   the recording's upper body kept, new legs and path.
 */
export function editControls(mode, motion, fromS = 0, toS = 0) {
  if (!kEditModes.includes(mode)) throw new Error(`unknown edit mode '${mode}'`);
  if (mode === 'new') return null;
  if (!motion || !motion.positions?.length) throw new Error('record a dance first (Record, then play a song)');
  const file = { file: JSON.stringify(motion), start_ms: 0 };
  if (mode === 'upper') return { given_lower: file };
  if (mode === 'lower') return { given_upper: file };
  const start = motion.audio_offset_s * 1000;
  const end = start + (motion.positions.length / (motion.fps || 30)) * 1000;
  const a = Math.max(start, fromS * 1000);
  const b = Math.min(end, toS * 1000);
  if (!(b > a)) throw new Error(`nothing to re-dance: ${fromS}-${toS} s is outside the recording (${(start / 1000).toFixed(1)}-${(end / 1000).toFixed(1)} s)`);
  const known = [];
  if (a > start) known.push({ start_ms: start, end_ms: a, joints: ['all'] });
  if (end > b) known.push({ start_ms: b, end_ms: end, joints: ['all'] });
  return { inpaint: file, inpaint_known: known };
}

/**
 * Runs one edit; resolves with the result message, rejects with the server's error (message, code).
 * `onEvent` sees every queued / progress message. `signal` (an AbortSignal) closes the socket, which
 * cancels the job on the server.
 */
export function runEdit(songBytes, request, onEvent = () => {}, { signal, url = wsUrl('ws/edit') } = {}) {
  return new Promise((resolve, reject) => {
    const ws = new WebSocket(url);
    ws.binaryType = 'arraybuffer';
    let settled = false;
    const settle = (fn, value) => {
      if (settled) return;
      settled = true;
      fn(value);
    };
    signal?.addEventListener('abort', () => {
      ws.close(1000, 'cancelled');
      settle(reject, Object.assign(new Error('edit cancelled'), { code: 'CANCELLED' }));
    });
    ws.onopen = () => {
      ws.send(JSON.stringify({ ...request, type: 'edit' }));
      ws.send(songBytes);
    };
    ws.onmessage = (ev) => {
      let msg;
      try {
        msg = JSON.parse(ev.data);
      } catch {
        return;
      }
      if (msg.type === 'result') settle(resolve, msg);
      else if (msg.type === 'error') settle(reject, Object.assign(new Error(msg.message || msg.code), { code: msg.code }));
      else onEvent(msg);
    };
    ws.onerror = () => settle(reject, new Error('the edit connection failed'));
    ws.onclose = (ev) => settle(reject, new Error(`the edit connection closed (${ev.code})`));
  });
}
