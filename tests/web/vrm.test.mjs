// The VRM avatar in the browser view, against a real dance-server (node --test; run by scripts/web-test.sh):
// headless Chromium loads the page with ?avatar=vrm, the bundled avatar (web/public/avatars/aachan.vrm,
// VRM 0.x) loads, a song file is performed and the avatar follows the stream: its bones change and its
// region of the screen changes; the avatar's skinned (raw) bones point along forward kinematics of the
// streamed frames on the SMPL skeleton (so left/right, the VRM 0.x mirror, the rotation convention and the
// rest-pose correction are right); the recorder's Save VRMA and a .vrma written by `dance-generate --vrma`
// load with @pixiv/three-vrm-animation and, played on the avatar, give its bones the rotations of the
// recording / the dance file at that time.
//
// DANCE_WEB_SCREENSHOTS=DIR saves web_vrm.png there.

import assert from 'node:assert/strict';
import { execFileSync } from 'node:child_process';
import { copyFileSync, existsSync, mkdtempSync, readFileSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { after, before, test } from 'node:test';
import { launchBrowser, openPage, pixelDifference, repo, startServer, waitFor } from './harness.mjs';
import { renderMusic, writeWav } from './music.mjs';

const work = mkdtempSync(join(tmpdir(), 'dance-vrm-test-'));
const song = join(work, 'song-120bpm.wav');
const shotsDir = process.env.DANCE_WEB_SCREENSHOTS || '';
let server;
let browser;
let page;
let errors;
const stats = () => page.evaluate(() => window.danceStats());

before(async () => {
  writeWav(song, renderMusic({ seconds: 40, bpm: 120, rate: 24000 }), 24000);
  server = await startServer();
  browser = await launchBrowser();
  ({ page, errors } = await openPage(browser, `${server.url}?avatar=vrm`));
});

after(async () => {
  await browser?.close();
  await server?.stop();
  rmSync(work, { recursive: true, force: true });
});

test('the bundled VRM avatar loads', async () => {
  const s = await waitFor(async () => { const x = await stats(); return x.avatar.active ? x : null; }, 'avatar', 30000);
  assert.equal(s.avatar.source, 'aachan.vrm');
  assert.equal(s.avatar.name, 'aachan');
  assert.equal(s.avatar.driven.length, 22, `driven bones ${s.avatar.driven}`);
  assert.deepEqual(errors, []);
});

test('the avatar dances to a song file', async () => {
  await page.click('#record-btn');
  await page.setInputFiles('#file-input', song);
  await waitFor(async () => (await stats()).avatar.poses >= 60, 'poses on the avatar', 40000);
  const arm = () => page.evaluate(() => window.danceAvatars.avatar.boneRotation('leftUpperArm'));
  const a = await arm();
  const box = (await stats()).dancerBox;
  assert.ok(box.width > 20 && box.height > 80, `avatar box ${JSON.stringify(box)}`);
  const pad = 40;
  const clip = {
    x: Math.max(0, box.x - pad), y: Math.max(0, box.y - pad),
    width: Math.min(1280 - Math.max(0, box.x - pad), box.width + 2 * pad),
    height: Math.min(720 - Math.max(0, box.y - pad), box.height + 2 * pad),
  };
  const first = await page.screenshot({ clip });
  await page.waitForTimeout(700);
  const second = await page.screenshot({ clip });
  const b = await arm();
  const diff = await pixelDifference(page, first, second);
  assert.ok(diff > 0.01, `only ${(100 * diff).toFixed(2)} % of the avatar's region changed`);
  assert.ok(Math.abs(a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3]) < 0.99999, 'the left upper arm did not move');
  const shot = join(work, 'vrm.png');
  await page.screenshot({ path: shot });
  if (shotsDir) copyFileSync(shot, join(shotsDir, 'web_vrm.png'));
  if (process.env.DANCE_VRM_SHOT) copyFileSync(shot, process.env.DANCE_VRM_SHOT);
  assert.deepEqual(errors, []);
});

test('the avatar\'s limbs point where the streamed frame\'s do', async () => {
  await page.click('#record-btn');  // stop recording
  await page.click('#stop-btn');
  const worst = await page.evaluate(() => {
    const frames = window.danceRecorder.frames.filter((f) => f.rotations);
    const av = window.danceAvatars.avatar;
    const sk = av.skeleton;
    const segments = [  // single bones: SMPL joint -> child joint, VRM bone -> child bone
      ['left_shoulder', 'left_elbow', 'leftUpperArm', 'leftLowerArm'],
      ['left_elbow', 'left_wrist', 'leftLowerArm', 'leftHand'],
      ['right_shoulder', 'right_elbow', 'rightUpperArm', 'rightLowerArm'],
      ['right_elbow', 'right_wrist', 'rightLowerArm', 'rightHand'],
      ['left_hip', 'left_knee', 'leftUpperLeg', 'leftLowerLeg'],
      ['left_knee', 'left_ankle', 'leftLowerLeg', 'leftFoot'],
      ['right_hip', 'right_knee', 'rightUpperLeg', 'rightLowerLeg'],
      ['right_knee', 'right_ankle', 'rightLowerLeg', 'rightFoot'],
      ['spine3', 'neck', 'upperChest', 'neck'],
      ['neck', 'head', 'neck', 'head'],
    ];
    // FK of the local rotations on the stream's skeleton (docs/rotations.md).
    const fk = (root, rot) => {
      const n = sk.parents.length; const g = []; const p = [];
      const mul = (a, b) => [a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
        a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
        a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
        a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0]];
      const rotate = (q, v) => { const r = mul(mul(q, [0, ...v]), [q[0], -q[1], -q[2], -q[3]]); return [r[1], r[2], r[3]]; };
      for (let j = 0; j < n; ++j) {
        const q = rot.slice(4 * j, 4 * j + 4);
        const par = sk.parents[j];
        if (par < 0) { g.push(q); p.push(root.slice(0, 3)); continue; }
        g.push(mul(g[par], q));
        const d = rotate(g[par], sk.restOffsets[j]);
        p.push([p[par][0] + d[0], p[par][1] + d[1], p[par][2] + d[2]]);
      }
      return p;
    };
    const dir = (a, b) => { const d = [b[0] - a[0], b[1] - a[1], b[2] - a[2]]; const l = Math.hypot(...d); return d.map((x) => x / l); };
    // The angle between the avatar's bone and the frame's, per segment, for one pose.
    const angles = (positions, rotations) => {
      av.setPose(positions, rotations);
      av.update(0);
      av.group.updateMatrixWorld(true);
      const p = fk(positions, rotations);
      const out = {};
      for (const [ja, jb, ba, bb] of segments) {
        const want = dir(p[sk.jointNames.indexOf(ja)], p[sk.jointNames.indexOf(jb)]);
        const wa = av.vrm.humanoid.getRawBoneNode(ba).getWorldPosition(av.pelvis.clone());
        const wb = av.vrm.humanoid.getRawBoneNode(bb).getWorldPosition(av.pelvis.clone());
        const got = dir(wa.toArray(), wb.toArray());
        out[ja] = Math.acos(Math.min(1, want[0] * got[0] + want[1] * got[1] + want[2] * got[2])) * 180 / Math.PI;
      }
      return out;
    };
    // With the rest correction (the default) the arm and leg bones point exactly along the frame's, at
    // rest (every rotation the identity) and posed; the neck and head bones, left uncorrected, keep the
    // angle they have at rest (rotations preserve angles between bones they turn together).
    const corrected = (j) => /_(shoulder|elbow|hip|knee)$/.test(j);
    const identity = Array.from({ length: 4 * sk.parents.length }, (_, i) => (i % 4 === 0 ? 1 : 0));
    const rest = angles([0, 0.95, 0], identity);
    const worstBySegment = {};
    for (const j of Object.keys(rest)) worstBySegment[j] = corrected(j) ? rest[j] : 0;
    for (const f of frames.filter((_, i) => i % 15 === 0).slice(0, 20)) {
      const a = angles(f.positions, f.rotations);
      for (const j of Object.keys(a)) {
        worstBySegment[j] = Math.max(worstBySegment[j], corrected(j) ? a[j] : Math.abs(a[j] - rest[j]));
      }
    }
    return { frames: frames.length, worstBySegment, rest };
  });
  assert.ok(worst.frames >= 60, `recorded ${worst.frames} frames`);
  // Uncorrected, SMPL's rest pose would leave the limbs 2-8 degrees off; a mirrored, swapped or
  // mis-converted rotation, tens of degrees (also for the neck and head).
  for (const [joint, deg] of Object.entries(worst.worstBySegment)) {
    assert.ok(deg < 0.1, `${joint}: the avatar's bone is ${deg.toFixed(2)} deg off the frame's (neck, head: ` +
      `off their rest angle ${worst.rest[joint].toFixed(1)}) (${JSON.stringify(worst.worstBySegment)})`);
  }
  console.log('avatar bone vs frame, worst deg:', JSON.stringify(worst.worstBySegment));
});

test('the recorder\'s Save VRMA plays back on the avatar with the recorded rotations', async () => {
  const [download] = await Promise.all([page.waitForEvent('download'), page.click('#save-vrma')]);
  assert.match(download.suggestedFilename(), /\.vrma$/);
  const bytes = readFileSync(await download.path()).toString('base64');
  const r = await page.evaluate(async (b64) => {
    const buf = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0)).buffer;
    const av = window.danceAvatars;
    const motion = window.danceRecorder.toMotion();
    const info = await av.playVrma(buf, 'recorded.vrma');
    const names = motion.joint_names;
    let worst = 0;
    for (const frame of [0, 10, motion.rotations.length - 1]) {
      av.avatar.seekVrma(frame / 30);
      for (const [smpl, bone] of [['left_elbow', 'leftLowerArm'], ['right_hip', 'rightUpperLeg'], ['neck', 'neck']]) {
        const q = motion.rotations[frame][names.indexOf(smpl)];
        const got = av.avatar.boneRotation(bone);
        worst = Math.max(worst, 1 - Math.abs(q[0] * got[3] + q[1] * got[0] + q[2] * got[1] + q[3] * got[2]));
      }
    }
    av.stopVrma();
    return { info, worst, frames: motion.rotations.length };
  }, bytes);
  assert.equal(r.info.tracks, 23);
  assert.ok(Math.abs(r.info.duration - (r.frames - 1) / 30) < 1e-3, `duration ${r.info.duration}`);
  assert.ok(r.worst < 1e-5, `bone rotations off the recording's by 1 - |dot| = ${r.worst}`);
  assert.deepEqual(errors, []);
});

test('a .vrma from dance-generate plays on the avatar with the dance file\'s rotations', async (t) => {
  const buildDir = process.env.DANCE_BUILD_DIR || join(repo, 'build');
  const generate = join(buildDir, 'bin/dance-generate');
  if (!existsSync(generate)) { t.skip(`no ${generate}`); return; }
  const clickSong = join(work, 'short.wav');
  writeWav(clickSong, renderMusic({ seconds: 6, bpm: 120, rate: 24000 }), 24000);
  execFileSync(generate, ['--audio', clickSong, '--model', join(repo, 'models/test-tiny.dncw'), '--seed', '1',
    '--out', join(work, 'd.json'), '--vrma', join(work, 'd.vrma'), '--quiet']);
  const dance = JSON.parse(readFileSync(join(work, 'd.json'), 'utf8'));
  const bytes = readFileSync(join(work, 'd.vrma')).toString('base64');
  const r = await page.evaluate(async ([b64, rotations, names]) => {
    const buf = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0)).buffer;
    const av = window.danceAvatars;
    const info = await av.playVrma(buf, 'd.vrma');
    const vrmNames = { left_shoulder: 'leftUpperArm', right_knee: 'rightLowerLeg', spine3: 'upperChest', pelvis: 'hips' };
    let worst = 0;
    for (const frame of [0, 17, 60, rotations.length - 1]) {
      av.avatar.seekVrma(frame / 30);
      for (const [smpl, bone] of Object.entries(vrmNames)) {
        const q = rotations[frame][names.indexOf(smpl)];  // (w, x, y, z)
        const got = av.avatar.boneRotation(bone);        // (x, y, z, w)
        const dot = Math.abs(q[0] * got[3] + q[1] * got[0] + q[2] * got[1] + q[3] * got[2]);
        worst = Math.max(worst, 1 - dot);
      }
    }
    av.stopVrma();
    return { info, worst };
  }, [bytes, dance.rotations, dance.joint_names]);
  assert.equal(r.info.tracks, 23, 'one rotation track per humanoid bone (22) and the hips translation');
  assert.ok(Math.abs(r.info.duration - (dance.rotations.length - 1) / 30) < 1e-3, `duration ${r.info.duration}`);
  assert.ok(r.worst < 1e-5, `bone rotations off the dance file's by 1 - |dot| = ${r.worst}`);
  assert.deepEqual(errors, []);
});
