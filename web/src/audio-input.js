// The two ways music gets into a session from the page: a song file, or the microphone.
//
// FileStreamer: decodes a file with WebAudio, streams it as mono float32 PCM at 24 kHz (the engine's rate,
//   so the server does not resample) in real time, a little ahead of the clock, and plays the original
//   (full quality) in the page, delayed by the model latency + a jitter margin, so frames and music meet.
// MicStreamer: getUserMedia (echo cancellation, noise suppression and auto gain off: they damage music),
//   an AudioWorklet taps the input, blocks of ~20 ms are streamed. Nothing is played back (the music is in
//   the room).
// Both pace themselves by the AudioContext clock and pause sending while the socket's send buffer is over
// `kMaxBufferedBytes` (a slow network must not build an unbounded backlog).

const kStreamRate = 24000;
const kMaxBufferedBytes = 1 << 20;

/** Decodes `arrayBuffer` into {buffer (AudioBuffer, original), mono24k (Float32Array)}. */
export async function decodeSong(ctx, arrayBuffer) {
  const buffer = await ctx.decodeAudioData(arrayBuffer);
  const frames = Math.ceil(buffer.duration * kStreamRate);
  const offline = new OfflineAudioContext(1, Math.max(1, frames), kStreamRate);
  const src = offline.createBufferSource();
  src.buffer = buffer;  // the destination is mono: WebAudio downmixes (speakers rule) and resamples
  src.connect(offline.destination);
  src.start();
  const rendered = await offline.startRendering();
  return { buffer, mono24k: rendered.getChannelData(0) };
}

export class FileStreamer {
  /**
   * @param {AudioContext} ctx
   * @param {{buffer: AudioBuffer, mono24k: Float32Array}} song  from decodeSong
   */
  constructor(ctx, song) {
    this.ctx = ctx;
    this.song = song;
    this.sampleRate = kStreamRate;
    this.sent = 0;
    this.timer = null;
    this.source = null;
    this.gain = ctx.createGain();
    this.gain.connect(ctx.destination);
    this.songStartCtx = NaN;
    this.onEnded = null;
    this.onChunk = null;  // (Float32Array of 24 kHz mono) => void, for every chunk sent
  }

  get durationS() { return this.song.buffer.duration; }

  /**
   * Starts streaming into `connection` (already performing) now, and the song's playback at
   * now + `delayS`. Returns the AudioContext time at which song sample 0 plays.
   */
  start(connection, delayS, { leadS = 0.25 } = {}) {
    this.stop();
    const sendStart = this.ctx.currentTime;
    this.songStartCtx = sendStart + delayS;
    this.source = this.ctx.createBufferSource();
    this.source.buffer = this.song.buffer;
    this.source.connect(this.gain);
    this.source.start(this.songStartCtx);
    this.source.onended = () => this.onEnded?.();
    const data = this.song.mono24k;
    this.sent = 0;
    const pump = () => {
      const due = Math.min(data.length, Math.floor((this.ctx.currentTime - sendStart + leadS) * kStreamRate));
      while (this.sent < due && connection.bufferedAmount < kMaxBufferedBytes) {
        const n = Math.min(due - this.sent, 4800);
        const chunk = data.slice(this.sent, this.sent + n);
        if (!connection.sendAudio(chunk)) return;
        this.onChunk?.(chunk);
        this.sent += n;
      }
      if (this.sent >= data.length) {
        clearInterval(this.timer);
        this.timer = null;
        connection.end();
      }
    };
    this.timer = setInterval(pump, 40);
    pump();
    return this.songStartCtx;
  }

  setVolume(v) { this.gain.gain.value = v; }

  stop() {
    if (this.timer) clearInterval(this.timer);
    this.timer = null;
    if (this.source) {
      this.source.onended = null;
      try { this.source.stop(); } catch { /* never started */ }
      this.source.disconnect();
      this.source = null;
    }
  }
}

export class MicStreamer {
  /** @param {AudioContext} ctx */
  constructor(ctx) {
    this.ctx = ctx;
    this.stream = null;
    this.node = null;
    this.input = null;
    this.sink = null;
    this.pending = [];
    this.pendingFrames = 0;
    this.level = 0;  // RMS of the last block, for the UI meter
    this.onChunk = null;  // (Float32Array mono at sampleRate) => void, for every block sent
  }

  get sampleRate() { return this.ctx.sampleRate; }

  /** Asks for the microphone (the browser prompts); rejects if refused or absent. */
  async open() {
    this.stream = await navigator.mediaDevices.getUserMedia({
      audio: { echoCancellation: false, noiseSuppression: false, autoGainControl: false, channelCount: 1 },
    });
    await this.ctx.audioWorklet.addModule(new URL('capture-worklet.js', document.baseURI).toString());
    this.input = this.ctx.createMediaStreamSource(this.stream);
    this.node = new AudioWorkletNode(this.ctx, 'dance-capture', { numberOfOutputs: 1 });
    // The worklet must be pulled by the graph to run: route it through a silent gain to the destination.
    this.sink = this.ctx.createGain();
    this.sink.gain.value = 0;
    this.input.connect(this.node).connect(this.sink).connect(this.ctx.destination);
  }

  /** Streams microphone blocks of ~`blockMs` into `connection` until stop(). */
  start(connection, { blockMs = 20 } = {}) {
    const blockFrames = Math.round(this.ctx.sampleRate * blockMs / 1000);
    this.node.port.onmessage = (ev) => {
      const block = ev.data;
      this.pending.push(block);
      this.pendingFrames += block.length;
      if (this.pendingFrames < blockFrames) return;
      const out = new Float32Array(this.pendingFrames);
      let o = 0;
      let energy = 0;
      for (const b of this.pending) {
        out.set(b, o);
        o += b.length;
        for (let i = 0; i < b.length; ++i) energy += b[i] * b[i];
      }
      this.level = Math.sqrt(energy / Math.max(1, out.length));
      this.pending = [];
      this.pendingFrames = 0;
      if (connection.bufferedAmount < kMaxBufferedBytes && connection.sendAudio(out)) this.onChunk?.(out);
    };
  }

  stop() {
    if (this.node) this.node.port.onmessage = null;
    for (const n of [this.input, this.node, this.sink]) n?.disconnect();
    this.stream?.getTracks().forEach((t) => t.stop());
    this.stream = null;
    this.node = this.input = this.sink = null;
    this.pending = [];
    this.pendingFrames = 0;
  }
}
