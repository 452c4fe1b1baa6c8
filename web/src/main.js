// The page: wires the panel, the WebSocket connection, the music inputs, the playout clock, the dancer and
// the recorder together, and runs the display loop (one pose per display refresh, interpolated).
//
// URL parameters: ?session=ID watches that session at load; ?drive=rotations drives the body by forward
// kinematics; ?jitter=MS sets the extra audio delay. window.danceStats() reports the live numbers (the
// end-to-end test in tests/web reads them).

import './style.css';
import { Connection, styleMix } from './connection.js';
import { Dancer } from './dancer.js';
import { FrameBuffer } from './frame-buffer.js';
import { AudioPlayoutClock, ArrivalPlayoutClock } from './playout-clock.js';
import { Recorder, downloadText } from './recorder.js';
import { Skeleton } from './skeleton.js';
import { Stage, isSoftwareGl } from './stage.js';
import { FrameTimer, RateMeter } from './stats.js';
import { FileStreamer, MicStreamer, decodeSong } from './audio-input.js';
import { fetchModel, fetchSessions, sessionLabel } from './sessions.js';
import { AvatarView } from './avatar-view.js';
import { downloadBytes, motionToVrma } from './vrma-export.js';
import { Directions } from './directions.js';
import { editControls, runEdit } from './editor.js';

const $ = (id) => document.getElementById(id);
const params = new URLSearchParams(window.location.search);

const ui = {
  status: $('status'), file: $('file-input'), mic: $('mic-btn'), stop: $('stop-btn'),
  micMeter: $('mic-meter'), micLevel: $('mic-level'), sessions: $('session-select'),
  refresh: $('refresh-btn'), watch: $('watch-btn'), style: $('style-select'), temperature: $('temperature'),
  temperatureValue: $('temperature-value'), drive: $('drive-select'), jitter: $('jitter'),
  jitterValue: $('jitter-value'), record: $('record-btn'), recordCount: $('record-count'),
  saveJson: $('save-json'), saveBvh: $('save-bvh'), beatDot: $('beat-dot'), hint: $('hint'),
  statSession: $('stat-session'), statRate: $('stat-rate'), statDisplay: $('stat-display'),
  statLatency: $('stat-latency'), statAhead: $('stat-ahead'), statUnderruns: $('stat-underruns'),
};

// Software GL (no GPU) cannot afford shadows and antialiasing at display rate: ?quality=low|high overrides.
const stage = new Stage($('view'), { quality: params.get('quality') || (isSoftwareGl() ? 'low' : 'high') });
let skeleton = new Skeleton();
let dancer = new Dancer(skeleton);
stage.add(dancer.group);
dancer.showRestPose();
// The body: capsules or a VRM avatar (avatar-view.js); ?avatar=vrm picks the VRM at load.
const avatars = new AvatarView(stage, {
  select: $('body-select'), fileInput: $('vrm-input'), skeleton: () => skeleton, onStatus: (t, s) => setStatus(t, s),
});
if (params.get('avatar') === 'vrm') avatars.choose('vrm');
// A floor path, a seed clip and keyframes for the next song; clicks that steer the dancer during one.
const directions = new Directions(stage, {
  draw: $('path-btn'), clear: $('path-clear'), speed: $('path-speed'), speedValue: $('path-speed-value'),
  seed: $('seed-input'), keys: $('keys-input'), summary: $('directions-summary'),
}, { onSteer: (steer) => sendControl({ steer }) });

const frames = new FrameBuffer();
const recorder = new Recorder();
const frameRate = new RateMeter(2000);
const displayTimer = new FrameTimer();
let connection = null;
let clock = null;
let audioCtx = null;
let streamer = null;  // FileStreamer | MicStreamer | null
let beats = [];       // pending beat times (ms, audio timeline)
let beatsShown = 0;
const recentBeats = [];  // audio times of the last pulses shown
let firstFrameAt = 0;    // performance.now() of the connection's first and latest frames
let lastFrameAt = 0;
let lastControl = null;
let lastEvent = null;
let controlsApplied = 0;  // control_applied events on this page (events can share a frame index)
let mode = 'idle';    // idle | file | mic | watch | edit
let lastSong = null;  // the last song file played (what an edit dances to)
let editor = null;    // the server's editor description (api/model "editor"), null = none
let editAbort = null;
let editSource = null;  // the AudioBufferSourceNode playing an edited dance's song
let lastEdit = null;    // {model_id, frames, windows, steps, compute_ms, audio_ms} of the last edit played
// Frames arrive in bursts of one model step (4 frames, 133 ms): a clock driven by arrivals buffers a step.
const kStepMs = 4000 / 30;

if (params.get('drive') === 'rotations') ui.drive.value = 'rotations';
if (params.get('jitter')) ui.jitter.value = params.get('jitter');
ui.jitterValue.textContent = ui.jitter.value;
dancer.setMode(ui.drive.value);

function setStatus(text, state = 'info') {
  ui.status.textContent = text;
  ui.status.dataset.state = state;
}

function audioContext() {
  if (!audioCtx) audioCtx = new AudioContext({ latencyHint: 'playback' });
  return audioCtx;
}

// ---- connection ---------------------------------------------------------------------------------------

function newConnection() {
  stopAll();
  frames.clear();
  beats = [];
  const c = new Connection({
    onInfo: onInfo,
    onFrame: (msg) => {
      if (c !== connection) return;
      if (frames.push(msg)) {
        frameRate.tick();
        const now = performance.now();
        if (!firstFrameAt) firstFrameAt = now;
        lastFrameAt = now;
        clock?.onFrame(msg.time_ms);
        recorder.push(msg);
        directions.noteFrame(msg);
        ui.hint.textContent = '';
      }
    },
    onBeat: (msg) => {
      if (c !== connection) return;
      beats.push(msg.time_ms);  // the server's beat (KIND_BEAT), cued on the playout clock below
    },
    onEvent: (msg) => {
      if (c !== connection) return;
      lastEvent = msg;
      if (msg.kind === 'control_applied') ++controlsApplied;
      if (msg.kind === 'control_applied') setStatus(`applied at frame ${msg.frame_index}`, 'live');
      else if (msg.kind === 'warning') {
        console.info('server warning:', msg.message);
        setStatus(`server: ${msg.message}`, 'warning');
      }
    },
    onEnd: (msg) => {
      if (c === connection) setStatus(`ended: ${msg.reason || 'done'}, ${msg.frames ?? '?'} frames`);
    },
    onError: (msg) => {
      if (c !== connection) return;
      console.warn('server error:', msg);
      setStatus(`server: ${msg.message || msg.code || 'error'}`, 'error');
    },
    onClose: (ev) => {
      if (c !== connection) return;
      if (ui.status.dataset.state === 'live') setStatus(`stream closed (${ev.code || 'closed'})`, 'info');
      if (streamer) streamer.stop?.();
      ui.stop.disabled = true;
    },
  });
  connection = c;
  firstFrameAt = lastFrameAt = 0;
  return c;
}


/** Style and temperature change a session we perform; a watched session belongs to its performer. */
function enableControls(on) {
  ui.style.disabled = !on;
  ui.temperature.disabled = !on;
}

function onInfo(info) {
  const next = new Skeleton(info);
  if (JSON.stringify(next.restOffsets) !== JSON.stringify(skeleton.restOffsets) ||
      JSON.stringify(next.parents) !== JSON.stringify(skeleton.parents)) {
    skeleton = next;
    dancer.dispose();
    dancer = new Dancer(skeleton);
    dancer.setMode(ui.drive.value);
    stage.add(dancer.group);
    dancer.showRestPose();
    avatars.onSkeleton(skeleton);
  } else {
    skeleton = next;
  }
  setStyles(info.styles);
  ui.statSession.textContent = info.session_id ?? '-';
  ui.statLatency.textContent = info.latency_ms !== undefined ? `${Number(info.latency_ms).toFixed(0)} ms` : '-';
  setStatus(`live: ${mode === 'watch' ? 'watching' : mode} (session ${info.session_id ?? '?'})`, 'live');
  ui.stop.disabled = false;
}

function setStyles(list) {
  const styles = (list || []).map((s) => (typeof s === 'string' ? s : s.name)).filter(Boolean);
  const keep = ui.style.value;
  ui.style.replaceChildren(new Option('none', 'none'), ...styles.map((s) => new Option(s, s)));
  ui.style.value = styles.includes(keep) ? keep : 'none';
}

function stopAll() {
  if (streamer) streamer.stop();
  streamer = null;
  ui.micMeter.hidden = true;
  if (connection) {
    connection.end();
    connection.close();
  }
  connection = null;
  if (editSource) {
    try { editSource.stop(); } catch { /* not started */ }
  }
  editSource = null;
  clock = null;
  mode = 'idle';
  directions.setPerforming(false);
  ui.stop.disabled = true;
}

function currentSettings() {
  return { style: styleMix(ui.style.value), temperature: Number(ui.temperature.value),
    controls: directions.startControls() };
}

// ---- the three ways in --------------------------------------------------------------------------------

async function playFile(file) {
  try {
    const ctx = audioContext();
    await ctx.resume();
    setStatus(`decoding ${file.name}...`);
    const song = await decodeSong(ctx, await file.arrayBuffer());
    const c = newConnection();
    mode = 'file';
    enableControls(true);
    setStatus('connecting...');
    const info = await c.perform({ sampleRate: 24000, ...currentSettings() });
    directions.setPerforming(true);
    streamer = new FileStreamer(ctx, song);
    const delayS = (Number(info.latency_ms) || 0) / 1000 + Number(ui.jitter.value) / 1000;
    clock = new AudioPlayoutClock(ctx, streamer.start(c, delayS));
    setStatus(`live: ${file.name} (session ${info.session_id ?? '?'})`, 'live');
  } catch (err) {
    console.warn(err);
    setStatus(`could not play ${file.name}: ${err.message}`, 'error');
  }
}

async function useMicrophone() {
  try {
    const ctx = audioContext();
    await ctx.resume();
    const c = newConnection();
    mode = 'mic';
    enableControls(true);
    const mic = new MicStreamer(ctx);
    setStatus('asking for the microphone...');
    await mic.open();
    streamer = mic;
    clock = new ArrivalPlayoutClock({ bufferMs: kStepMs + Number(ui.jitter.value) / 2 });
    await c.perform({ sampleRate: mic.sampleRate, ...currentSettings() });
    directions.setPerforming(true);
    mic.start(c);
    ui.micMeter.hidden = false;
  } catch (err) {
    console.warn(err);
    stopAll();
    setStatus(`microphone: ${err.message}`, 'error');
  }
}

async function watchSession(id) {
  if (!id) return;
  try {
    const c = newConnection();
    mode = 'watch';
    enableControls(false);
    clock = new ArrivalPlayoutClock({ bufferMs: kStepMs + Number(ui.jitter.value) });
    setStatus(`connecting to session ${id}...`);
    await c.watch(id);
  } catch (err) {
    console.warn(err);
    setStatus(`watch ${id}: ${err.message}`, 'error');
  }
}

async function refreshSessions() {
  try {
    const list = await fetchSessions();
    const keep = ui.sessions.value;
    const options = list.map((s) => new Option(sessionLabel(s), s.id));
    ui.sessions.replaceChildren(...(options.length ? options : [new Option('(no sessions)', '')]));
    if (list.some((s) => String(s.id) === keep)) ui.sessions.value = keep;
    ui.watch.disabled = !ui.sessions.value;
  } catch (err) {
    console.warn('sessions:', err.message);
  }
}

// ---- panel events -------------------------------------------------------------------------------------

ui.file.addEventListener('change', () => {
  const file = ui.file.files[0];
  if (file) {
    lastSong = file;
    updateEditButton();
    playFile(file);
  }
  ui.file.value = '';
});

// ---- the diffusion editor -----------------------------------------------------------------------------

function updateEditButton() {
  const btn = $('edit-btn');
  btn.disabled = !editor || !lastSong || Boolean(editAbort);
  btn.title = !editor ? 'this server has no editor model' : !lastSong ? 'play a song file first' :
    `dance ${lastSong.name} with ${editor.model_id}`;
}

async function playEdited(result, song) {
  stopAll();
  const ctx = audioContext();
  await ctx.resume();
  const decoded = await decodeSong(ctx, await song.arrayBuffer());
  frames.clear();
  recorder.start({ skeleton, fps: result.fps || 30, modelId: result.model_id });
  for (const f of result.frames) {
    frames.push(f);
    recorder.push(f);
  }
  recorder.stop();
  const src = ctx.createBufferSource();
  src.buffer = decoded.buffer;
  src.connect(ctx.destination);
  const start = ctx.currentTime + 0.3;
  src.start(start);
  editSource = src;
  clock = new AudioPlayoutClock(ctx, start);
  mode = 'edit';
  ui.stop.disabled = false;
  src.onended = () => { if (editSource === src) setStatus(`edited dance ended (${song.name})`); };
}

async function startEdit() {
  if (!lastSong || !editor) return;
  const song = lastSong;
  const status = $('edit-status');
  const bar = $('edit-progress');
  let request;
  try {
    const controls = editControls($('edit-mode').value, recorder.length ? recorder.toMotion() : null,
      Number($('edit-from').value), Number($('edit-to').value));
    request = { style: styleMix(ui.style.value), seed: Math.floor(Math.random() * 1e6),
      steps: Math.max(0, Math.round(Number($('edit-steps').value) || 0)), audio_name: song.name };
    if (controls) request.controls = controls;
  } catch (err) {
    status.textContent = err.message;
    return;
  }
  editAbort = new AbortController();
  updateEditButton();
  $('edit-cancel').hidden = false;
  bar.hidden = false;
  bar.value = 0;
  status.textContent = 'sending...';
  try {
    const result = await runEdit(await song.arrayBuffer(), request, (ev) => {
      if (ev.type === 'queued') status.textContent = ev.position ? `waiting (${ev.position} ahead)` : 'starting...';
      if (ev.type === 'progress') {
        bar.value = ev.steps_total ? ev.steps_done / ev.steps_total : 0;
        status.textContent = `denoising ${ev.steps_done} / ${ev.steps_total}`;
      }
    }, { signal: editAbort.signal });
    lastEdit = { model_id: result.model_id, frames: result.frames.length, windows: result.windows,
      steps: result.steps, compute_ms: result.compute_ms, audio_ms: result.audio_ms };
    status.textContent = `${result.frames.length} frames in ${(result.compute_ms / 1000).toFixed(1)} s`;
    setStatus(`edited: ${song.name} (${result.model_id})`, 'live');
    await playEdited(result, song);
  } catch (err) {
    status.textContent = err.code === 'CANCELLED' ? 'cancelled' : `edit failed: ${err.message}`;
  } finally {
    editAbort = null;
    bar.hidden = true;
    $('edit-cancel').hidden = true;
    updateEditButton();
  }
}

$('edit-btn').addEventListener('click', startEdit);
$('edit-cancel').addEventListener('click', () => editAbort?.abort());
ui.mic.addEventListener('click', useMicrophone);
ui.stop.addEventListener('click', () => { stopAll(); setStatus('stopped'); });
ui.refresh.addEventListener('click', refreshSessions);
ui.sessions.addEventListener('change', () => { ui.watch.disabled = !ui.sessions.value; });
ui.watch.addEventListener('click', () => watchSession(ui.sessions.value));
ui.drive.addEventListener('change', () => dancer.setMode(ui.drive.value));
ui.jitter.addEventListener('input', () => { ui.jitterValue.textContent = ui.jitter.value; });

/** Sends a live change; true if it went out (a connection is open). */
function sendControl(change) {
  lastControl = change;
  const sent = Boolean(connection?.control(change));
  if (sent) setStatus(`sent ${Object.keys(change).join(', ')}`, 'live');
  return sent;
}
ui.style.addEventListener('change', () => sendControl({ style: styleMix(ui.style.value) }));
ui.temperature.addEventListener('input', () => {
  ui.temperatureValue.textContent = Number(ui.temperature.value).toFixed(2);
});
ui.temperature.addEventListener('change', () => sendControl({ temperature: Number(ui.temperature.value) }));

ui.record.addEventListener('click', () => {
  if (recorder.recording) {
    recorder.stop();
  } else {
    recorder.start({
      skeleton, fps: connection?.info?.fps || 30, sessionId: connection?.info?.session_id,
      latencyMs: connection?.info?.latency_ms, modelId: connection?.info?.model_id,
    });
  }
  ui.record.classList.toggle('on', recorder.recording);
  ui.record.textContent = recorder.recording ? '\u25a0 Stop recording' : '\u25cf Record';
});
const stamp = () => new Date().toISOString().replace(/[:.]/g, '-').slice(0, 19);
ui.saveJson.addEventListener('click', () => {
  downloadText(recorder.toJson(), `dance-${stamp()}.json`, 'application/json');
});
ui.saveBvh.addEventListener('click', () => {
  try {
    downloadText(recorder.toBvh(), `dance-${stamp()}.bvh`, 'text/plain');
  } catch (err) {
    setStatus(`BVH: ${err.message}`, 'error');
  }
});
$('save-vrma').addEventListener('click', () => {
  try {
    downloadBytes(motionToVrma(recorder.toMotion()), `dance-${stamp()}.vrma`, 'model/gltf-binary');
  } catch (err) {
    setStatus(`VRMA: ${err.message}`, 'error');
  }
});

// ---- display loop -------------------------------------------------------------------------------------

let lastTick = performance.now();
let lastPanel = 0;
function tick(now) {
  const dt = Math.min(0.1, (now - lastTick) / 1000);
  lastTick = now;
  displayTimer.tick(now);
  const t = clock ? clock.nowMs() : NaN;
  if (!Number.isNaN(t)) {
    const pose = frames.sample(t);
    if (pose) dancer.setPose(pose.positions, pose.rotations);
    if (pose) avatars.setPose(pose.positions, pose.rotations);
    while (beats.length && beats[0] <= t) {
      const b = beats.shift();
      if (t - b < 250) {  // a late beat is not a beat any more
        stage.pulse();
        ++beatsShown;
        recentBeats.push(b);
        if (recentBeats.length > 16) recentBeats.shift();
      }
    }
  }
  avatars.update(dt);
  dancer.group.visible = !avatars.active;
  stage.follow(avatars.active ? avatars.pelvis : dancer.pelvis, dt);
  ui.beatDot.style.opacity = String(0.12 + 0.88 * stage.pulseLevel);
  ui.beatDot.style.transform = `scale(${0.7 + 0.5 * stage.pulseLevel})`;
  stage.render();
  if (now - lastPanel > 250) {
    lastPanel = now;
    updatePanel(t);
  }
  requestAnimationFrame(tick);
}

function updatePanel(t) {
  const d = displayTimer.summary();
  ui.statRate.textContent = `${frameRate.rate().toFixed(1)} fps`;
  ui.statDisplay.textContent = `${(1000 / Math.max(1, d.meanMs)).toFixed(0)} fps`;
  ui.statAhead.textContent = frames.length && !Number.isNaN(t) ?
    `${Math.max(0, frames.lastTimeMs - t).toFixed(0)} ms` : '-';
  ui.statUnderruns.textContent = String(frames.underruns);
  ui.recordCount.textContent = `${recorder.length} frames`;
  ui.saveJson.disabled = ui.saveBvh.disabled = recorder.length === 0;
  $('save-vrma').disabled = recorder.length === 0;
  if (streamer instanceof MicStreamer) ui.micLevel.style.width = `${Math.min(100, streamer.level * 400)}%`;
}

window.danceStats = () => ({
  mode,
  connected: Boolean(connection?.open),
  sessionId: connection?.info?.session_id ?? null,
  latencyMs: connection?.info?.latency_ms ?? null,
  framesReceived: connection?.framesReceived ?? 0,
  frameRate: frameRate.rate(),
  frameRateTotal: frameRate.total,
  // Frames per second over the whole connection, by arrival time (robust to a stalled page thread).
  frameRateConnection: lastFrameAt > firstFrameAt ?
    ((connection?.framesReceived ?? 1) - 1) * 1000 / (lastFrameAt - firstFrameAt) : 0,
  streamFps: connection?.info?.fps ?? null,
  playoutMs: clock ? clock.nowMs() : null,
  bufferedAheadMs: clock && frames.length ? frames.lastTimeMs - clock.nowMs() : null,
  underruns: frames.underruns,
  beatsShown,
  recentBeats: recentBeats.slice(),
  display: displayTimer.summary(),
  lastControl,
  lastEvent,
  controlsApplied,
  style: ui.style.value,
  styles: Array.from(ui.style.options, (o) => o.value),
  dancerBox: stage.projectBox(avatars.active ? avatars.jointPoints() : dancer.jointPoints()),
  avatar: avatars.stats(),
  recorded: recorder.length,
  audioBytesSent: connection?.bytesSent ?? 0,
  directions: {
    path: directions.pathPoints(), steersSent: directions.steersSent, mode: directions.mode,
    seed: directions.seed?.name ?? null, keys: directions.keys?.name ?? null,
    dancer: directions.lastFrame,
  },
});
window.danceResetDisplayTimer = () => displayTimer.reset();
window.danceLastEdit = () => lastEdit;
window.danceRecorder = recorder;
window.danceAvatars = avatars;
window.danceDirections = directions;

fetchModel().then((model) => {
  setStyles(model.styles);
  editor = model.editor ?? null;
  $('edit-status').textContent = editor ? `editor ${editor.model_id}` : 'no editor on this server';
  updateEditButton();
  ui.statLatency.textContent = model.latency_ms !== undefined ? `${Number(model.latency_ms).toFixed(0)} ms` : '-';
}).catch((err) => console.info('api/model:', err.message));
refreshSessions();
setInterval(refreshSessions, 5000);
if (params.get('session')) watchSession(params.get('session'));
requestAnimationFrame(tick);
