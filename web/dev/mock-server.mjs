// DEV ONLY: a stand-in for dance-server's HTTP/WebSocket side, for iterating on the page without the
// engine. It speaks the browser protocol of docs/protocol.md with a synthetic dance (sine-driven joint
// rotations, forward kinematics over the SMPL rest skeleton). The end-to-end test never uses it.
//
//   node dev/mock-server.mjs [port]     then open http://localhost:PORT/ (serves web/dist)

import { createServer } from 'node:http';
import { readFile } from 'node:fs/promises';
import { extname, join, normalize } from 'node:path';
import { fileURLToPath } from 'node:url';
import * as THREE from 'three';
import { WebSocketServer } from 'ws';
import { Skeleton, forwardKinematics } from '../src/skeleton.js';

const port = Number(process.argv[2] || 8099);
const dist = fileURLToPath(new URL('../dist/', import.meta.url));
const skeleton = new Skeleton();
const kStyles = ['waltz', 'tango', 'rumba', 'chacha', 'salsa'];
const kFps = 30;
const kLatencyMs = 133.3;
const sessions = new Map();  // id -> {watchers: Set, style, temperature, frames}
let nextId = 1;

function pose(index, session) {
  const t = index / kFps;
  const beat = 2 * Math.PI * t * (session.bpm / 60);
  const amp = 0.4 * session.temperature;
  const rot = new Float32Array(96);
  const set = (j, axis, angle) => {
    const q = new THREE.Quaternion().setFromAxisAngle(axis, angle);
    rot[4 * j] = q.w; rot[4 * j + 1] = q.x; rot[4 * j + 2] = q.y; rot[4 * j + 3] = q.z;
  };
  for (let j = 0; j < 24; ++j) rot[4 * j] = 1;
  const X = new THREE.Vector3(1, 0, 0);
  const Y = new THREE.Vector3(0, 1, 0);
  const Z = new THREE.Vector3(0, 0, 1);
  set(0, Y, 0.3 * t);
  set(1, X, -amp * Math.sin(beat));
  set(2, X, amp * Math.sin(beat));
  set(4, X, amp * (1 + Math.sin(beat)));
  set(5, X, amp * (1 - Math.sin(beat)));
  set(16, Z, -1.0 + amp * Math.sin(beat));
  set(17, Z, 1.0 + amp * Math.cos(beat));
  set(18, Y, -0.8 * Math.abs(Math.sin(beat / 2)));
  set(19, Y, 0.8 * Math.abs(Math.cos(beat / 2)));
  set(15, X, 0.2 * Math.sin(beat));
  const root = [0.5 * Math.sin(0.2 * t), 0.93 + 0.03 * Math.cos(2 * beat), 0.5 * Math.cos(0.2 * t) - 0.5];
  const positions = forwardKinematics(skeleton, root, rot);
  return {
    type: 'frame', index, time_ms: (index * 1000) / kFps,
    positions: Array.from(positions, (v) => Math.round(v * 1e5) / 1e5),
    rotations: Array.from(rot, (v) => Math.round(v * 1e6) / 1e6),
    upper_code: index >> 2, lower_code: (index >> 2) % 512,
  };
}

function info(id, session) {
  return {
    type: 'info', session_id: id, fps: kFps, latency_ms: kLatencyMs, model_id: 'mock',
    joint_names: skeleton.jointNames, parents: skeleton.parents, rest_offsets: skeleton.restOffsets.flat(),
    styles: kStyles, style: session.style, temperature: session.temperature,
  };
}

function emit(session, msg) {
  const text = JSON.stringify(msg);
  for (const ws of session.watchers) if (ws.readyState === 1) ws.send(text);
}

function newSession(style = [], temperature = 1) {
  const id = String(nextId++);
  const session = { watchers: new Set(), style, temperature, frames: 0, bpm: 120, samples: 0, rate: 24000 };
  sessions.set(id, session);
  return [id, session];
}

// A session nobody performs into: generated in real time so that /ws/watch has something to show.
const [demoId, demo] = newSession([{ name: 'waltz', weight: 1 }]);
setInterval(() => {
  const msg = pose(demo.frames++, demo);
  emit(demo, msg);
  if (demo.frames % 15 === 0) emit(demo, { type: 'beat', time_ms: msg.time_ms });
}, 1000 / kFps);

const types = { '.html': 'text/html', '.js': 'text/javascript', '.css': 'text/css', '.png': 'image/png' };
const http = createServer(async (req, res) => {
  const url = new URL(req.url, 'http://x');
  if (url.pathname === '/api/sessions') {
    res.setHeader('content-type', 'application/json');
    res.end(JSON.stringify({ sessions: [...sessions].map(([id, s]) => ({
      session_id: id, client_name: id === demoId ? 'mock-demo' : 'browser', style: s.style,
      frames: s.frames, audio_ms: (s.frames * 1000) / kFps, viewers: s.watchers.size })) }));
    return;
  }
  if (url.pathname === '/healthz') { res.end('ok'); return; }
  if (url.pathname === '/api/model') {
    res.setHeader('content-type', 'application/json');
    const { type, session_id: _, ...model } = info('', demo);
    res.end(JSON.stringify(model));
    return;
  }
  const path = normalize(join(dist, url.pathname === '/' ? 'index.html' : url.pathname));
  if (!path.startsWith(dist)) { res.statusCode = 403; res.end(); return; }
  try {
    const body = await readFile(path);
    res.setHeader('content-type', types[extname(path)] || 'application/octet-stream');
    res.end(body);
  } catch {
    res.statusCode = 404;
    res.end('not found');
  }
});

const wss = new WebSocketServer({ server: http });
wss.on('connection', (ws, req) => {
  const url = new URL(req.url, 'http://x');
  if (url.pathname === '/ws/watch') {
    const id = url.searchParams.get('session');
    const s = sessions.get(id);
    if (!s) { ws.send(JSON.stringify({ type: 'error', code: 'NOT_FOUND', message: `no session ${id}` })); ws.close(); return; }
    ws.send(JSON.stringify(info(id, s)));
    s.watchers.add(ws);
    ws.on('message', (data, isBinary) => { if (!isBinary) control(s, JSON.parse(data)); });
    ws.on('close', () => s.watchers.delete(ws));
    return;
  }
  if (url.pathname !== '/ws/perform') { ws.close(1008, 'unknown path'); return; }
  let id = null;
  let s = null;
  ws.on('message', (data, isBinary) => {
    if (!isBinary) {
      const msg = JSON.parse(data);
      if (msg.type === 'start') {
        [id, s] = newSession(msg.style || [], msg.temperature ?? 1);
        s.rate = msg.sample_rate;
        s.watchers.add(ws);
        ws.send(JSON.stringify(info(id, s)));
      } else if (msg.type === 'control' && s) {
        control(s, msg);
      } else if (msg.type === 'end') {
        setTimeout(() => {
          ws.send(JSON.stringify({ type: 'end', frames: s.frames, audio_ms: (s.frames * 1000) / kFps,
                                   reason: 'end_of_audio' }));
          ws.close(1000, 'end of audio');
        }, 200);
      }
      return;
    }
    if (!s) return;
    s.samples += data.length / 4;
    const due = Math.floor((s.samples / s.rate) * kFps);
    while (s.frames < due) {
      const msg = pose(s.frames++, s);
      emit(s, msg);
      if (s.frames % 15 === 0) emit(s, { type: 'beat', time_ms: msg.time_ms });
    }
  });
  ws.on('close', () => { if (id) sessions.delete(id); });
});

function control(s, msg) {
  if (msg.style !== undefined) s.style = msg.style;
  if (msg.temperature !== undefined) s.temperature = msg.temperature;
  emit(s, { type: 'event', kind: 'control_applied', time_ms: (s.frames * 1000) / kFps, frame_index: s.frames });
  console.log('control', JSON.stringify(msg));
}

http.listen(port, () => console.log(`mock dance-server on http://localhost:${port}/ (demo session ${demoId})`));
