// The body on stage: the capsule dancer (dancer.js) or a VRM avatar (vrm-avatar.js), chosen in the panel.
// The page's own avatar is web/public/avatars/aachan.vrm (MIT, Perfume Dev Team; licence beside it); any
// .vrm dropped on the page (or picked with the file button) replaces it, and a dropped .vrma (VRM
// Animation, e.g. from `dance-generate --vrma`) plays on the avatar until the next stream or Stop.
//
// Usage:
//   const avatars = new AvatarView(stage, { select, fileInput, skeleton: () => skeleton, onStatus });
//   every display frame: avatars.setPose(positions, rotations); avatars.update(dt);
//   avatars.active: true while the VRM is shown (the capsules are hidden then)
// ?avatar=vrm in the page address chooses the VRM at load; ?retarget=0 drives it with the rotations as
// they are, without the rest-pose correction (vrm-avatar.js). Not thread-safe.

// three-vrm is loaded on first use (a separate chunk): the capsule page does not pay for it.
const loadVrmModule = () => import('./vrm-avatar.js');

export const kDefaultAvatarUrl = 'avatars/aachan.vrm';

export class AvatarView {
  constructor(stage, { select, fileInput, skeleton, onStatus = () => {} }) {
    this.stage = stage;
    this.select = select;
    this.skeleton = skeleton;
    this.onStatus = onStatus;
    this.avatar = null;
    this.loading = null;
    this.poses = 0;      // poses applied to the avatar
    this.source = null;  // what the current avatar was loaded from
    this.vrma = null;    // {duration, tracks} of a playing .vrma
    select?.addEventListener('change', () => this.choose(select.value));
    fileInput?.addEventListener('change', () => {
      const f = fileInput.files[0];
      if (f) this.loadFile(f);
      fileInput.value = '';
    });
    window.addEventListener('dragover', (e) => { e.preventDefault(); });
    window.addEventListener('drop', (e) => {
      const f = [...(e.dataTransfer?.files || [])].find((x) => /\.vrma?$/i.test(x.name));
      if (!f) return;
      e.preventDefault();
      this.loadFile(f);
    });
  }

  get active() { return this.select?.value === 'vrm' && this.avatar !== null; }

  async choose(value) {
    if (this.select) this.select.value = value;
    if (value === 'vrm' && !this.avatar && !this.loading) await this._load(kDefaultAvatarUrl, 'aachan.vrm');
    if (this.avatar) this.avatar.group.visible = value === 'vrm';
  }

  /** A .vrm becomes the avatar; a .vrma plays on it. */
  async loadFile(file) {
    const bytes = await file.arrayBuffer();
    if (/\.vrma$/i.test(file.name)) return this.playVrma(bytes, file.name);
    await this._load(bytes, file.name);
    await this.choose('vrm');
    return null;
  }

  async playVrma(bytes, name = '.vrma') {
    if (!this.avatar) await this.choose('vrm');
    if (!this.avatar) return null;
    try {
      this.vrma = await this.avatar.playVrma(bytes);
      this.onStatus(`playing ${name} (${this.vrma.duration.toFixed(1)} s) on ${this.avatar.name}`, 'info');
    } catch (err) {
      console.warn(err);
      this.onStatus(`${name}: ${err.message}`, 'error');
    }
    return this.vrma;
  }

  stopVrma() {
    this.avatar?.stopVrma();
    this.vrma = null;
  }

  async _load(source, name) {
    const retarget = new URLSearchParams(window.location.search).get('retarget') !== '0';
    this.loading = loadVrmModule().then(({ VrmAvatar }) => VrmAvatar.load(source, this.skeleton(), { retarget }));
    try {
      const next = await this.loading;
      this.avatar?.dispose();
      this.avatar = next;
      this.source = name;
      this.poses = 0;
      this.vrma = null;
      this.stage.add(next.group);
      this.onStatus(`avatar: ${next.name} (${next.driven.length} bones driven)`, 'info');
    } catch (err) {
      console.warn(err);
      this.onStatus(`avatar ${name}: ${err.message}`, 'error');
    } finally {
      this.loading = null;
    }
  }

  /** The stream's skeleton changed (a new model). */
  onSkeleton(skeleton) { this.avatar?.setSkeleton(skeleton); }

  setPose(positions, rotations) {
    if (!this.active || !rotations) return;
    this.avatar.setPose(positions, rotations);
    ++this.poses;
  }

  update(dt) { if (this.avatar) this.avatar.update(dt); }

  get pelvis() { return this.avatar?.pelvis; }

  jointPoints() { return this.avatar ? this.avatar.jointPoints() : []; }

  stats() {
    return {
      active: this.active, name: this.avatar?.name ?? null, source: this.source, poses: this.poses,
      driven: this.avatar?.driven ?? [], vrma: this.vrma, retarget: this.avatar?.retarget ?? null,
    };
  }
}
