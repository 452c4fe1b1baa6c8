// Takes the documentation screenshots (docs/images/web_*.png) with a real dance-server: the page at full
// quality (shadows, antialiasing) performing a song, and a second page watching that session.
//
//   cd web && node ../tests/web/screenshots.mjs [song file] [out dir=../docs/images]
// Model: DANCE_MODEL, else models/default.dncw if present, else models/test-tiny.dncw (random weights: its
// dance is noise). Song: the argument, else a generated 120 BPM song.

import { existsSync, mkdtempSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join, resolve } from 'node:path';
import { collectErrors, launchBrowser, repo, startServer, waitFor } from './harness.mjs';
import { renderMusic, writeWav } from './music.mjs';

const work = mkdtempSync(join(tmpdir(), 'dance-web-shots-'));
let song = process.argv[2];
const outDir = resolve(process.argv[3] || join(repo, 'docs/images'));
if (!song) {
  song = join(work, 'song.wav');
  writeWav(song, renderMusic({ seconds: 60, bpm: 120, rate: 24000 }), 24000);
}
if (!process.env.DANCE_MODEL && existsSync(join(repo, 'models/default.dncw'))) {
  process.env.DANCE_MODEL = join(repo, 'models/default.dncw');
}

const server = await startServer();
const browser = await launchBrowser();
try {
  const page = await browser.context.newPage();
  const errors = collectErrors(page);
  await page.goto(`${server.url}?quality=high`);
  await page.waitForFunction(() => typeof window.danceStats === 'function');
  await page.setInputFiles('#file-input', song);
  await waitFor(async () => (await page.evaluate(() => window.danceStats())).framesReceived > 30, 'frames', 30000);
  await page.waitForTimeout(8000);
  // Catch the moment of a beat pulse, so the ring shows.
  await page.waitForFunction(() => document.getElementById('beat-dot').style.opacity > 0.6, null,
                             { timeout: 5000 }).catch(() => {});
  await page.screenshot({ path: join(outDir, 'web_perform.png') });

  const { sessionId } = await page.evaluate(() => window.danceStats());
  const viewer = await browser.context.newPage();
  await viewer.goto(`${server.url}?quality=high&session=${encodeURIComponent(sessionId)}`);
  await waitFor(async () => (await viewer.evaluate(() => window.danceStats())).framesReceived > 30, 'watch');
  await viewer.waitForTimeout(2000);
  await viewer.screenshot({ path: join(outDir, 'web_watch.png') });
  const model = await (await fetch(new URL('api/model', server.url))).json();
  console.log(`screenshots in ${outDir} (model ${model.model_id}, song ${song}); console errors: ${errors.length}`);
} finally {
  await browser.close();
  await server.stop();
  rmSync(work, { recursive: true, force: true });
}
