// The browser side of the dance-server WebSocket protocol (docs/protocol.md).
//
//   const c = new Connection({onInfo, onFrame, onBeat, onEvent, onEnd, onError, onClose});
//   await c.watch(sessionId);                 // ws/watch?session=ID: frames of someone else's session
//   await c.perform({sampleRate, style, temperature, seed});   // ws/perform: our own session
//   c.sendAudio(float32Array);  c.control({style, temperature});  c.end();  c.close();
//
// Messages from the server are JSON text: info (first), frame, beat, event, end (last), error; unknown types
// go to onMessage.
// Audio goes up as binary messages of little-endian float32 mono PCM at the sample rate given in `start`.
// Every callback runs on the page's thread. `bufferedAmount` is exposed so senders can back off.

/** The page's ?token= (servers run with --auth-token want it on /api and /ws requests), or ''. */
export function authToken() {
  return new URLSearchParams(window.location.search).get('token') || '';
}

/** `path` resolved against the page's address, with the auth token appended when there is one. */
export function apiUrl(path, base = document.baseURI) {
  const u = new URL(path, base);
  if (authToken()) u.searchParams.set('token', authToken());
  return u;
}

/** The ws:// or wss:// URL of `path` on the server that served the page. */
export function wsUrl(path, base = document.baseURI) {
  const u = apiUrl(path, base);
  u.protocol = u.protocol === 'https:' ? 'wss:' : 'ws:';
  return u.toString();
}

/** A style value for the protocol from a UI choice: '' or 'none' = no style, else [{name, weight: 1}]. */
export function styleMix(name) {
  return !name || name === 'none' ? [] : [{ name, weight: 1 }];
}

export class Connection {
  constructor(handlers = {}) {
    this.handlers = handlers;
    this.ws = null;
    this.info = null;
    this.mode = null;  // 'watch' | 'perform'
    this.ended = null;  // the server's `end` message, once it came
    this.framesReceived = 0;
    this.bytesSent = 0;
  }

  get open() { return this.ws !== null && this.ws.readyState === WebSocket.OPEN; }
  get bufferedAmount() { return this.ws ? this.ws.bufferedAmount : 0; }

  /** Watches session `id`; resolves with the info message. */
  watch(id) {
    this.mode = 'watch';
    return this._open(wsUrl(`ws/watch?session=${encodeURIComponent(id)}`), null);
  }

  /**
   * Starts a session of our own; resolves with the info message.
   * @param {{sampleRate: number, style?: Array, temperature?: number, seed?: number, controls?: object}} opts
   *   controls: StreamHeader.controls in JSON (docs/protocol.md): trajectory, seed, keyframes, ...
   */
  perform({ sampleRate, style = [], temperature, seed, controls }) {
    this.mode = 'perform';
    const start = { type: 'start', sample_rate: sampleRate, channels: 1, style, client_name: 'browser' };
    if (temperature !== undefined) start.temperature = temperature;
    if (seed !== undefined) start.seed = seed;
    if (controls !== undefined) start.controls = controls;
    return this._open(wsUrl('ws/perform'), start);
  }

  _open(url, startMessage) {
    this.close();
    return new Promise((resolve, reject) => {
      let settled = false;
      const ws = new WebSocket(url);
      ws.binaryType = 'arraybuffer';
      this.ws = ws;
      ws.onopen = () => { if (startMessage) ws.send(JSON.stringify(startMessage)); };
      ws.onmessage = (ev) => {
        if (typeof ev.data !== 'string') return;  // the protocol sends text only
        let msg;
        try { msg = JSON.parse(ev.data); } catch { return; }
        switch (msg.type) {
          case 'info':
            this.info = msg;
            this.handlers.onInfo?.(msg);
            if (!settled) { settled = true; resolve(msg); }
            break;
          case 'frame':
            ++this.framesReceived;
            this.handlers.onFrame?.(msg);
            break;
          case 'beat':
            this.handlers.onBeat?.(msg);
            break;
          case 'event':
            this.handlers.onEvent?.(msg);
            break;
          case 'end':
            this.ended = msg;
            this.handlers.onEnd?.(msg);
            break;
          case 'error':
            this.handlers.onError?.(msg);
            if (!settled) { settled = true; reject(new Error(msg.message || msg.code || 'server error')); }
            break;
          default:
            this.handlers.onMessage?.(msg);
        }
      };
      ws.onerror = () => {
        if (!settled) { settled = true; reject(new Error(`cannot connect to ${url}`)); }
      };
      ws.onclose = (ev) => {
        if (this.ws === ws) this.ws = null;
        if (!settled) { settled = true; reject(new Error(`closed before info (code ${ev.code})`)); }
        this.handlers.onClose?.(ev);
      };
    });
  }

  /** Sends mono float32 PCM (a Float32Array) on a perform connection. */
  sendAudio(samples) {
    if (!this.open || this.mode !== 'perform') return false;
    // Float32Array memory is little-endian on every platform browsers run on.
    this.ws.send(samples.buffer.byteLength === samples.byteLength ? samples.buffer : samples.slice().buffer);
    this.bytesSent += samples.byteLength;
    return true;
  }

  /** Changes the live session: {style?: Array, temperature?: number, steer?: object, controls?: object}. */
  control(change) {
    if (!this.open) return false;
    this.ws.send(JSON.stringify({ type: 'control', ...change }));
    return true;
  }

  /** Ends our audio; the server flushes the last frames and closes. */
  end() {
    if (this.open && this.mode === 'perform') this.ws.send(JSON.stringify({ type: 'end' }));
  }

  close() {
    if (this.ws) {
      const ws = this.ws;
      this.ws = null;
      ws.onclose = null;
      ws.close();
      this.handlers.onClose?.({ code: 1000, reason: 'closed by page' });
    }
  }
}
