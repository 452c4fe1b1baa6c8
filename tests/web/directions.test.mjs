// Directing the dancer from the browser (node --test; run by scripts/web-test.sh): headless Chromium draws
// a floor path with clicks, plays a song with it (the path goes in the start message), checks that the
// dancer from the real dance-server (the shipped model) ends where the path ends, then steers it with a
// click on the floor during the song and checks that it gets there; and a bad keyframes file is refused
// by the server with the reason shown on the page.
//
// DANCE_WEB_SCREENSHOTS=DIR also saves the path screenshot there (docs/images/web_path.png).

import assert from 'node:assert/strict';
import { copyFileSync, mkdtempSync, rmSync, writeFileSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { after, before, test } from 'node:test';
import { launchBrowser, openPage, repo, startServer, waitFor } from './harness.mjs';
import { renderMusic, writeWav } from './music.mjs';

const work = mkdtempSync(join(tmpdir(), 'dance-web-directions-'));
const song = join(work, 'song-120bpm.wav');
const shotsDir = process.env.DANCE_WEB_SCREENSHOTS || '';
let server;
let browser;
let page;
let errors;
const stats = () => page.evaluate(() => window.danceStats());

before(async () => {
  writeWav(song, renderMusic({ seconds: 40, bpm: 120, rate: 24000 }), 24000);
  // The shipped model: it follows a path (the test model's random weights would not show it).
  process.env.DANCE_MODEL = process.env.DANCE_MODEL || join(repo, 'models/default.dncw');
  server = await startServer();
  browser = await launchBrowser();
  ({ page, errors } = await openPage(browser, server.url));
});

after(async () => {
  await browser?.close();
  await server?.stop();
  rmSync(work, { recursive: true, force: true });
});

// Clicks the canvas at fractions (fx, fy) of its size.
async function clickView(fx, fy) {
  const box = await page.locator('#view canvas').boundingBox();
  await page.mouse.click(box.x + fx * box.width, box.y + fy * box.height);
}

const distance = (a, b) => Math.hypot(a.x - b.x, a.z - b.z);

test('a path drawn on the floor is danced along', async () => {
  await page.click('#path-btn');
  assert.equal((await stats()).directions.mode, 'draw');
  // Three clicks on the floor in front of the camera: the start, then two points to walk to.
  await clickView(0.5, 0.8);
  await clickView(0.3, 0.75);
  await clickView(0.35, 0.9);
  await page.click('#path-btn');  // done drawing
  const s = await stats();
  const path = s.directions.path;
  assert.equal(path.length, 3, JSON.stringify(path));
  for (let i = 1; i < path.length; ++i) assert.ok(path[i].t_ms > path[i - 1].t_ms);
  const length = distance(path[0], path[1]) + distance(path[1], path[2]);
  assert.ok(length > 0.5, `the clicks landed on the floor ${length.toFixed(2)} m apart`);
  if (shotsDir) await page.screenshot({ path: join(shotsDir, 'web_path_drawn.png') });

  await page.setInputFiles('#file-input', song);
  const end = path[path.length - 1];
  // Once the playout is 1.5 s past the path's end, the dancer stands at its end.
  const at = await waitFor(async () => {
    const x = await stats();
    return x.playoutMs !== null && x.playoutMs > end.t_ms + 1500 && x.directions.dancer ? x : null;
  }, 'the song past the end of the path', 60000);
  const d = distance(at.directions.dancer, end);
  assert.ok(d < 0.5, `the dancer is ${d.toFixed(2)} m from the path's end ${JSON.stringify(end)}`);
  if (shotsDir) {
    await page.screenshot({ path: join(work, 'path.png') });
    copyFileSync(join(work, 'path.png'), join(shotsDir, 'web_path.png'));
  }
  assert.deepEqual(errors, []);
});

test('a click on the floor during the song steers the dancer there', async () => {
  await page.click('#path-btn');
  assert.equal((await stats()).directions.mode, 'steer');
  const before = (await stats()).directions;
  await clickView(0.7, 0.85);
  const s = await waitFor(async () => {
    const x = await stats();
    return x.directions.steersSent > before.steersSent && x.lastEvent?.kind === 'control_applied' ? x : null;
  }, 'the steer sent and applied', 10000);
  const target = s.lastControl.steer.point;
  assert.ok(distance(target, s.directions.dancer) > 0.3, 'the target is somewhere else');
  const arrived = await waitFor(async () => {
    const x = await stats();
    return x.playoutMs > target.t_ms + 1000 ? x : null;
  }, 'the song past the steer target time', 30000);
  const d = distance(arrived.directions.dancer, target);
  assert.ok(d < 0.5, `the dancer is ${d.toFixed(2)} m from the target ${JSON.stringify(target)}`);
  await page.click('#path-btn');
  await page.click('#stop-btn');
});

test('a bad keyframes file is refused with the reason on the page', async () => {
  await page.click('#path-clear');
  const bad = join(work, 'keys.json');
  writeFileSync(bad, JSON.stringify({ format: 'dance-motion/v1', positions: [] }));
  await page.setInputFiles('#keys-input', bad);
  await waitFor(async () => ((await stats()).directions.keys === 'keys.json'), 'the keyframes file loaded');
  await page.setInputFiles('#file-input', song);
  const status = await waitFor(async () => {
    const t = await page.textContent('#status');
    return /keyframes/.test(t) ? t : null;
  }, 'the server\'s reason on the page', 20000);
  assert.match(status, /keyframes/);
  // Refused: nothing plays (the Stop button stays disabled) and the page still works for the next song.
  assert.equal(await page.isDisabled('#stop-btn'), true);
  await page.click('#path-clear');
  assert.equal((await stats()).directions.keys, null);
});
