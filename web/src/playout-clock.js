// Playout clocks: which audio time (ms on the stream's input timeline) the page shows right now.
//
// Two sources of truth:
//  - AudioPlayoutClock: the page plays the song itself. Song sample 0 plays at AudioContext time
//    `songStartCtx`, which the caller sets to "when streaming started + the model latency the server reports
//    + a jitter margin". Showing the frame of audio time (ctx.currentTime - songStartCtx) keeps the dancer on
//    the music as heard, because a frame's time_ms is the audio time of its start.
//  - ArrivalPlayoutClock: the music is not played by the page (watching someone else's session, or the
//    microphone, where the music is in the room). Frames are shown `bufferMs` after the earliest arrival
//    seen for their audio time, tracking the server's clock by the minimum of (arrival - time_ms) over a
//    sliding window of frames, and slewing smoothly when that estimate moves.

export class AudioPlayoutClock {
  /** @param {AudioContext} ctx  @param {number} songStartCtx seconds, AudioContext time of song sample 0 */
  constructor(ctx, songStartCtx) {
    this.ctx = ctx;
    this.songStartCtx = songStartCtx;
  }

  onFrame() {}

  /**
   * Audio time in ms shown now (may be negative before the song starts): the song time leaving the
   * speakers, i.e. the context time minus the output latency (large on Bluetooth headsets).
   */
  nowMs() {
    const heard = this.ctx.currentTime - (this.ctx.outputLatency || 0);
    return (heard - this.songStartCtx) * 1000;
  }
}

export class ArrivalPlayoutClock {
  constructor({ bufferMs = 120, windowFrames = 300, now = () => performance.now() } = {}) {
    this.bufferMs = bufferMs;
    this.windowFrames = windowFrames;
    this.now = now;
    this.offsets = [];   // recent (arrival - time_ms), ms
    this.target = NaN;   // the window minimum
    this.offset = NaN;   // the slewed offset in use
    this.lastNow = NaN;
  }

  /** Call on every received frame message. */
  onFrame(timeMs) {
    const offset = this.now() - timeMs;
    this.offsets.push(offset);
    if (this.offsets.length > this.windowFrames) this.offsets.shift();
    let min = Infinity;
    for (const o of this.offsets) if (o < min) min = o;
    this.target = min;
    if (Number.isNaN(this.offset)) this.offset = min;
  }

  nowMs() {
    const now = this.now();
    if (Number.isNaN(this.offset)) return NaN;
    // Slew toward the target at most 5 % of the elapsed time: speed changes of the dance stay invisible.
    if (!Number.isNaN(this.lastNow)) {
      const maxStep = 0.05 * (now - this.lastNow);
      const d = this.target - this.offset;
      this.offset += Math.max(-maxStep, Math.min(maxStep, d));
    }
    this.lastNow = now;
    return now - this.offset - this.bufferMs;
  }
}
