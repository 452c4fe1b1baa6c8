// The diffusion editor from the browser (node --test; run by scripts/web-test.sh): headless Chromium
// records a live dance, sends it with the song to the real dance-server's /ws/edit (the editor loaded from
// models/sgmd-tiny.dncw: random weights, so this checks the plumbing, not the dance) to re-dance two
// seconds of it, and plays the result with the song: the kept frames are the recording's, the edited
// span is new, and the recorder holds the edited dance for saving.

import assert from 'node:assert/strict';
import { mkdtempSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { after, before, test } from 'node:test';
import { launchBrowser, openPage, repo, startServer, waitFor } from './harness.mjs';
import { renderMusic, writeWav } from './music.mjs';

const work = mkdtempSync(join(tmpdir(), 'dance-web-edit-'));
const song = join(work, 'song-6s.wav');
let server;
let browser;
let page;
let errors;
const stats = () => page.evaluate(() => window.danceStats());

before(async () => {
  writeWav(song, renderMusic({ seconds: 6, bpm: 120, rate: 24000 }), 24000);
  server = await startServer({ editorModel: join(repo, 'models/sgmd-tiny.dncw') });
  browser = await launchBrowser();
  ({ page, errors } = await openPage(browser, server.url));
});

after(async () => {
  await browser?.close();
  await server?.stop();
  rmSync(work, { recursive: true, force: true });
});

test('the page finds the server\'s editor', async () => {
  await waitFor(async () => (await page.textContent('#edit-status')).includes('sgmd-tiny'), 'the editor named');
  assert.equal(await page.isDisabled('#edit-btn'), true, 'no song yet: nothing to edit');
});

test('a recorded dance is re-danced between two times and played with the song', async () => {
  await page.click('#record-btn');
  await page.setInputFiles('#file-input', song);
  await waitFor(async () => (await stats()).playoutMs > 5500, 'the song played', 30000);
  await page.click('#record-btn');  // stop recording
  const recorded = await page.evaluate(() => window.danceRecorder.toMotion());
  assert.ok(recorded.positions.length > 120, `recorded ${recorded.positions.length} frames`);
  await waitFor(async () => !(await page.isDisabled('#edit-btn')), 'the edit button enabled');

  await page.selectOption('#edit-mode', 'inpaint');
  await page.fill('#edit-from', '2');
  await page.fill('#edit-to', '4');
  await page.fill('#edit-steps', '6');
  await page.click('#edit-btn');
  const done = await waitFor(() => page.evaluate(() => window.danceLastEdit()), 'the edit result', 60000);
  assert.equal(done.model_id, 'sgmd-tiny');
  assert.equal(done.steps, 6);
  assert.ok(Math.abs(done.frames - 180) <= 1, `${done.frames} frames for a 6-s song`);
  await waitFor(async () => (await stats()).mode === 'edit' && (await stats()).playoutMs > 500,
    'the edited dance playing', 20000);

  const edited = await page.evaluate(() => window.danceRecorder.toMotion());
  const at = (m, t) => m.positions[Math.round(t * 30) - m.frame_indices[0]];
  const diff = (a, b) => Math.max(...a.flatMap((p, j) => p.map((v, k) => Math.abs(v - b[j][k]))));
  for (const t of [1.0, 5.0]) {
    assert.ok(diff(at(edited, t), at(recorded, t)) < 1e-3, `kept frame at ${t} s moved`);
  }
  assert.ok(diff(at(edited, 3.0), at(recorded, 3.0)) > 1e-2, 'the edited span is the same as before');
  assert.equal(await page.textContent('#edit-status').then((s) => /frames in/.test(s)), true);
  assert.deepEqual(errors, []);
});

test('a bad span is refused on the page before anything is sent', async () => {
  await page.selectOption('#edit-mode', 'inpaint');
  await page.fill('#edit-from', '40');
  await page.fill('#edit-to', '50');
  await page.click('#edit-btn');
  await waitFor(async () => (await page.textContent('#edit-status')).includes('nothing to re-dance'), 'the refusal');
});
