// Directing the dancer from the page (docs/controls.md): draw a floor path the dance follows, load a seed
// clip or keyframes from a file, and, while a song plays, click the floor to send the dancer there.
//
//   const directions = new Directions(stage, elements, { onSteer: (steer) => connection.control({ steer }) });
//   connection.perform({ ..., controls: directions.startControls() });   // the path, seed and keys
//   directions.noteFrame(frame);                                         // each frame: where the dancer is
//
// The path: each click on the floor (in "draw" mode, before a song starts) adds a point; the dancer starts
// at the first and walks the rest at the chosen speed (the points' times follow from their distances). While
// performing, a click in "steer" mode sends Control.steer: be at that point after the walk there.
import * as THREE from 'three';

const kStartS = 0.5;        // the path's first point: where the dancer stands at this audio time
const kMinSteerS = 1.0;     // a steer target is at least this far ahead of the newest frame

export class Directions {
  /**
   * @param {import('./stage.js').Stage} stage
   * @param {{draw: HTMLButtonElement, clear: HTMLButtonElement, speed: HTMLInputElement,
   *          speedValue: HTMLElement, seed: HTMLInputElement, keys: HTMLInputElement,
   *          summary: HTMLElement}} el
   * @param {{onSteer: (steer: object) => boolean}} hooks
   */
  constructor(stage, el, hooks) {
    this.stage = stage;
    this.el = el;
    this.hooks = hooks;
    this.mode = 'off';        // 'off' | 'draw' (before a song: the path) | 'steer' (while performing)
    this.performing = false;
    this.points = [];         // [{x, z}] on the floor
    this.seed = null;         // {name, text}
    this.keys = null;
    this.steersSent = 0;
    this.lastFrame = null;    // {time_ms, x, z}
    this.target = null;       // the last steer target {x, z}
    this.group = new THREE.Group();
    stage.add(this.group);
    this._raycaster = new THREE.Raycaster();
    this._floor = new THREE.Plane(new THREE.Vector3(0, 1, 0), 0);

    el.draw.addEventListener('click', () => this.setMode(this.mode === 'off' ? (this.performing ? 'steer' : 'draw') : 'off'));
    el.clear.addEventListener('click', () => {
      this.points = [];
      this.target = null;
      this.seed = this.keys = null;
      this._redraw();
    });
    el.speed.addEventListener('input', () => { el.speedValue.textContent = Number(el.speed.value).toFixed(1); this._summary(); });
    el.seed.addEventListener('change', () => this._loadFile(el.seed, 'seed'));
    el.keys.addEventListener('change', () => this._loadFile(el.keys, 'keys'));
    // A click (not an orbit drag) on the canvas puts a point on the floor.
    const canvas = stage.renderer.domElement;
    let down = null;
    canvas.addEventListener('pointerdown', (ev) => { down = { x: ev.clientX, y: ev.clientY }; });
    canvas.addEventListener('pointerup', (ev) => {
      if (!down || Math.hypot(ev.clientX - down.x, ev.clientY - down.y) > 5 || this.mode === 'off') return;
      const p = this._floorPoint(ev);
      if (p) this._click(p);
    });
    this._summary();
  }

  setMode(mode) {
    this.mode = mode;
    this.el.draw.classList.toggle('active', mode !== 'off');
    this.el.draw.textContent = mode === 'off' ? (this.performing ? 'Steer by clicking the floor' : 'Draw a path')
      : mode === 'draw' ? 'Drawing: click the floor (done)' : 'Steering: click the floor (done)';
    this.stage.controls.enabled = mode === 'off';
  }

  /** A song starts (true) or stops (false): clicks steer instead of drawing. */
  setPerforming(on) {
    this.performing = on;
    this.setMode('off');
  }

  /** The controls of a new performance (StreamHeader.controls in JSON), or undefined if none. */
  startControls() {
    const c = {};
    const path = this.pathPoints();
    if (path.length >= 2) c.trajectory = path;
    if (this.seed) c.seed = { file: this.seed.text };
    if (this.keys) c.keyframes = { file: this.keys.text };
    return Object.keys(c).length ? c : undefined;
  }

  /** The drawn path as timed points [{t_ms, x, z}]: from kStartS, at the chosen speed. */
  pathPoints() {
    const speed = Math.max(0.1, Number(this.el.speed.value));
    let t = kStartS;
    return this.points.map((p, i) => {
      if (i > 0) t += Math.max(0.2, Math.hypot(p.x - this.points[i - 1].x, p.z - this.points[i - 1].z) / speed);
      return { t_ms: Math.round(t * 1000), x: p.x, z: p.z };
    });
  }

  /** Each frame received: where the dancer is (its pelvis) and when. */
  noteFrame(frame) {
    const p = frame.positions;
    this.lastFrame = { time_ms: frame.time_ms, x: p[0], z: p[2] };
  }

  _click(p) {
    if (this.mode === 'draw') {
      this.points.push(p);
      this._redraw();
      return;
    }
    if (this.mode === 'steer' && this.lastFrame) {
      const speed = Math.max(0.1, Number(this.el.speed.value));
      const walk = Math.hypot(p.x - this.lastFrame.x, p.z - this.lastFrame.z) / speed;
      const steer = { point: { t_ms: Math.round(this.lastFrame.time_ms + 1000 * Math.max(kMinSteerS, walk + 0.5)), x: p.x, z: p.z } };
      if (this.hooks.onSteer(steer)) {
        ++this.steersSent;
        this.target = p;
        this._redraw();
      }
    }
  }

  _floorPoint(ev) {
    const rect = this.stage.renderer.domElement.getBoundingClientRect();
    const ndc = new THREE.Vector2(((ev.clientX - rect.left) / rect.width) * 2 - 1,
      -((ev.clientY - rect.top) / rect.height) * 2 + 1);
    this._raycaster.setFromCamera(ndc, this.stage.camera);
    const hit = new THREE.Vector3();
    if (!this._raycaster.ray.intersectPlane(this._floor, hit)) return null;
    return { x: Math.round(hit.x * 100) / 100, z: Math.round(hit.z * 100) / 100 };
  }

  async _loadFile(input, which) {
    const file = input.files[0];
    input.value = '';
    if (!file) return;
    const text = await file.text();
    // The server reads both (dance-motion/v1 JSON or BVH) and says what is wrong with a bad one.
    this[which] = { name: file.name, text };
    this._summary();
  }

  _redraw() {
    this.group.clear();
    const mat = new THREE.LineBasicMaterial({ color: 0xffc44d });
    if (this.points.length >= 2) {
      const geo = new THREE.BufferGeometry().setFromPoints(this.points.map((p) => new THREE.Vector3(p.x, 0.01, p.z)));
      this.group.add(new THREE.Line(geo, mat));
    }
    const dot = new THREE.CircleGeometry(0.06, 20);
    this.points.forEach((p, i) => {
      const m = new THREE.Mesh(dot, new THREE.MeshBasicMaterial({ color: i === 0 ? 0x6dd36d : 0xffc44d }));
      m.rotation.x = -Math.PI / 2;
      m.position.set(p.x, 0.012, p.z);
      this.group.add(m);
    });
    if (this.target) {
      const ring = new THREE.Mesh(new THREE.RingGeometry(0.12, 0.18, 32), new THREE.MeshBasicMaterial({ color: 0x4dc3ff }));
      ring.rotation.x = -Math.PI / 2;
      ring.position.set(this.target.x, 0.012, this.target.z);
      this.group.add(ring);
    }
    this._summary();
  }

  _summary() {
    const parts = [];
    const path = this.pathPoints();
    if (path.length >= 2) parts.push(`path: ${path.length} points, ${(path[path.length - 1].t_ms / 1000).toFixed(1)} s`);
    else if (path.length === 1) parts.push('path: 1 point (click more)');
    if (this.seed) parts.push(`seed: ${this.seed.name}`);
    if (this.keys) parts.push(`keyframes: ${this.keys.name}`);
    this.el.summary.textContent = parts.length ? parts.join('; ') : 'free dance';
  }
}
