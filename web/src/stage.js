// The 3D stage: renderer, lights, a floor, a camera that follows the dancer, and the beat pulse.
//
// Usage:
//   const stage = new Stage(canvasParent);
//   stage.add(dancer.group);
//   every display frame: stage.follow(pelvisPosition, dtSeconds); stage.render();
//   on a beat: stage.pulse();
// The user can still orbit and zoom (OrbitControls); following moves the orbit target, not the angle.

import * as THREE from 'three';
import { OrbitControls } from 'three/examples/jsm/controls/OrbitControls.js';

const kMaxLag = 0.6;  // metres
const kLowQualityWidth = 720;  // pixels

export class Stage {
  /**
   * @param {HTMLElement} parent  the element the canvas fills
   * @param {{quality?: 'high'|'low'}} options  'low': no antialiasing, no shadows, at most 720 pixels wide
   *     (for software GL, e.g. headless Chromium without a GPU)
   */
  constructor(parent, { quality = 'high' } = {}) {
    this.parent = parent;
    const high = quality !== 'low';
    this.high = high;
    this.renderer = new THREE.WebGLRenderer({ antialias: high, powerPreference: 'high-performance' });
    this.renderer.setPixelRatio(high ? Math.min(window.devicePixelRatio || 1, 2) : 1);
    this.renderer.shadowMap.enabled = high;
    this.renderer.shadowMap.type = THREE.PCFShadowMap;
    this.renderer.domElement.id = 'stage-canvas';
    parent.appendChild(this.renderer.domElement);

    this.scene = new THREE.Scene();
    this.scene.background = new THREE.Color(0x14161c);
    this.scene.fog = new THREE.Fog(0x14161c, 8, 22);

    this.camera = new THREE.PerspectiveCamera(45, 1, 0.05, 100);
    this.camera.position.set(0.8, 1.6, 4.2);
    this.controls = new OrbitControls(this.camera, this.renderer.domElement);
    this.controls.target.set(0, 0.9, 0);
    this.controls.enableDamping = true;
    this.controls.minDistance = 1.2;
    this.controls.maxDistance = 12;
    this.controls.maxPolarAngle = Math.PI * 0.495;
    this.controls.update();

    this._addLights();
    this._addFloor();
    this._addPulse();

    this.followTarget = new THREE.Vector3(0, 0.9, 0);
    this.pulseLevel = 0;
    this._resize = () => this.resize();
    window.addEventListener('resize', this._resize);
    this.resize();
  }

  _addLights() {
    this.scene.add(new THREE.HemisphereLight(0xbfd4ff, 0x2a2320, 1.1));
    const key = new THREE.DirectionalLight(0xffffff, 2.2);
    key.position.set(3, 6, 4);
    key.castShadow = true;
    key.shadow.mapSize.set(1024, 1024);
    const s = key.shadow.camera;
    s.left = -3; s.right = 3; s.top = 3; s.bottom = -3; s.near = 1; s.far = 20;
    this.keyLight = key;
    this.scene.add(key, key.target);
  }

  _addFloor() {
    const floor = new THREE.Mesh(
      new THREE.CircleGeometry(30, 64),
      new THREE.MeshStandardMaterial({ color: 0x2b2f3a, roughness: 0.9, metalness: 0.0 }));
    floor.rotation.x = -Math.PI / 2;
    floor.receiveShadow = true;
    this.scene.add(floor);
    const grid = new THREE.GridHelper(30, 60, 0x4a5366, 0x394050);
    grid.position.y = 0.001;
    this.scene.add(grid);
  }

  _addPulse() {
    // A ring on the floor under the dancer that flashes and grows on every beat.
    this.pulseMaterial = new THREE.MeshBasicMaterial({
      color: 0xffc857, transparent: true, opacity: 0, side: THREE.DoubleSide, depthWrite: false,
    });
    this.pulseRing = new THREE.Mesh(new THREE.RingGeometry(0.55, 0.68, 64), this.pulseMaterial);
    this.pulseRing.rotation.x = -Math.PI / 2;
    this.pulseRing.position.y = 0.004;
    this.scene.add(this.pulseRing);
  }

  add(object) { this.scene.add(object); }

  resize() {
    const w = Math.max(1, this.parent.clientWidth);
    const h = Math.max(1, this.parent.clientHeight);
    // Software GL pays per pixel: render at most kLowQualityWidth pixels wide and let CSS scale it up.
    if (!this.high) this.renderer.setPixelRatio(Math.min(1, kLowQualityWidth / w));
    this.renderer.setSize(w, h, false);
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
  }

  /** Flash the beat ring now. */
  pulse() { this.pulseLevel = 1; }

  /**
   * Moves the orbit target (and the camera with it) smoothly toward the dancer's pelvis.
   * @param {THREE.Vector3|null} pelvis  world position, or null to stay
   * @param {number} dt  seconds since the last call
   */
  follow(pelvis, dt) {
    if (pelvis) {
      const goal = new THREE.Vector3(pelvis.x, 0.9, pelvis.z);
      const k = 1 - Math.exp(-dt * 2.5);  // ~0.4 s time constant: follows travel, ignores sway
      const before = this.followTarget.clone();
      this.followTarget.lerp(goal, k);
      // Fast travel: never lag more than kMaxLag metres behind, so the dancer stays in the picture.
      const lag = this.followTarget.distanceTo(goal);
      if (lag > kMaxLag) this.followTarget.lerp(goal, 1 - kMaxLag / lag);
      const delta = this.followTarget.clone().sub(before);
      this.controls.target.add(delta);
      this.camera.position.add(delta);
      this.pulseRing.position.x = pelvis.x;
      this.pulseRing.position.z = pelvis.z;
      this.keyLight.position.set(pelvis.x + 3, 6, pelvis.z + 4);
      this.keyLight.target.position.set(pelvis.x, 0, pelvis.z);
    }
    this.pulseLevel *= Math.exp(-dt * 6);
    this.pulseMaterial.opacity = 0.9 * this.pulseLevel;
    const scale = 1 + 0.35 * (1 - this.pulseLevel);
    this.pulseRing.scale.set(scale, scale, scale);
  }

  render() {
    this.controls.update();
    this.renderer.render(this.scene, this.camera);
  }

  /** The dancer's screen-space bounding box in CSS pixels for the given world points (for tests). */
  projectBox(points) {
    const rect = this.renderer.domElement.getBoundingClientRect();
    let x0 = Infinity; let y0 = Infinity; let x1 = -Infinity; let y1 = -Infinity;
    const v = new THREE.Vector3();
    for (const p of points) {
      v.copy(p).project(this.camera);
      const x = rect.left + (v.x + 1) / 2 * rect.width;
      const y = rect.top + (1 - v.y) / 2 * rect.height;
      x0 = Math.min(x0, x); y0 = Math.min(y0, y); x1 = Math.max(x1, x); y1 = Math.max(y1, y);
    }
    return { x: x0, y: y0, width: x1 - x0, height: y1 - y0 };
  }
}

/** True when WebGL runs in software (SwiftShader, llvmpipe): no GPU to spend. */
export function isSoftwareGl() {
  try {
    const gl = document.createElement('canvas').getContext('webgl2');
    const ext = gl?.getExtension('WEBGL_debug_renderer_info');
    const name = ext ? gl.getParameter(ext.UNMASKED_RENDERER_WEBGL) : '';
    gl?.getExtension('WEBGL_lose_context')?.loseContext();
    return /swiftshader|llvmpipe|software/i.test(name);
  } catch {
    return false;
  }
}
