// Rate and timing meters for the status panel and the tests (window.danceStats).

/** Events per second over a sliding window of the last `windowMs`. */
export class RateMeter {
  constructor(windowMs = 2000, now = () => performance.now()) {
    this.windowMs = windowMs;
    this.now = now;
    this.times = [];
    this.total = 0;
  }

  tick() {
    const t = this.now();
    this.times.push(t);
    ++this.total;
    this._trim(t);
  }

  _trim(t) {
    while (this.times.length && this.times[0] < t - this.windowMs) this.times.shift();
  }

  /** Events per second in the window (0 until two events). */
  rate() {
    this._trim(this.now());
    if (this.times.length < 2) return 0;
    const span = this.times[this.times.length - 1] - this.times[0];
    return span > 0 ? ((this.times.length - 1) * 1000) / span : 0;
  }
}

/**
 * Display-frame timing: a histogram-free summary of frame intervals since the last reset
 * (count, mean, worst, and intervals over 2x the median refresh period = visible hitches).
 */
export class FrameTimer {
  constructor() { this.reset(); }

  reset() {
    this.count = 0;
    this.sum = 0;
    this.max = 0;
    this.long = 0;
    this.last = NaN;
    this.recent = [];
  }

  tick(t) {
    if (!Number.isNaN(this.last)) {
      const dt = t - this.last;
      ++this.count;
      this.sum += dt;
      if (dt > this.max) this.max = dt;
      this.recent.push(dt);
      if (this.recent.length > 240) this.recent.shift();
      const sorted = this.recent.slice().sort((a, b) => a - b);
      const median = sorted[sorted.length >> 1];
      if (this.recent.length > 30 && dt > 2 * median) ++this.long;
    }
    this.last = t;
  }

  summary() {
    return {
      frames: this.count,
      meanMs: this.count ? this.sum / this.count : 0,
      fps: this.sum > 0 ? (this.count * 1000) / this.sum : 0,
      maxMs: this.max,
      hitches: this.long,
    };
  }
}
