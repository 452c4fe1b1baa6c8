// Soak benchmark (not a test: prints numbers, asserts nothing): the page performing a long song against a
// real dance-server, measuring once a minute the display frame rate, the worst display frame interval,
// hitches (intervals over twice the median), the frame rate received, playout underruns, the JS heap and
// the machine's load average (the display rate of software GL depends on what else runs).
//
//   cd web && node ../tests/web/soak.mjs [minutes=10] [quality=auto|low|high]
// Same environment as the e2e test (DANCE_BUILD_DIR, DANCE_MODEL, DANCE_SERVER_URL).

import { mkdtempSync, rmSync } from 'node:fs';
import { loadavg, tmpdir } from 'node:os';
import { join } from 'node:path';
import { collectErrors, launchBrowser, startServer, waitFor } from './harness.mjs';
import { renderMusic, writeWav } from './music.mjs';

const minutes = Number(process.argv[2] || 10);
const quality = process.argv[3] || 'auto';
const work = mkdtempSync(join(tmpdir(), 'dance-web-soak-'));
const song = join(work, 'song.wav');
writeWav(song, renderMusic({ seconds: minutes * 60 + 30, bpm: 124, rate: 24000 }), 24000);

const server = await startServer();
const browser = await launchBrowser();
try {
  const page = await browser.context.newPage();
  const errors = collectErrors(page);
  await page.goto(quality === 'auto' ? server.url : `${server.url}?quality=${quality}`);
  await page.waitForFunction(() => typeof window.danceStats === 'function');
  await page.setInputFiles('#file-input', song);
  await waitFor(async () => (await page.evaluate(() => window.danceStats())).framesReceived > 30, 'frames', 30000);
  console.log(`soak: ${minutes} min, viewport 1280x720, quality ${quality}, server ${server.url}`);
  console.log('minute | display fps | worst interval ms | hitches | frames in/s | underruns | heap MB | load 1m');
  let prevFrames = (await page.evaluate(() => window.danceStats())).framesReceived;
  let prevUnderruns = 0;
  const totals = { frames: 0, sumMs: 0, maxMs: 0, hitches: 0 };
  for (let m = 1; m <= minutes; ++m) {
    await page.evaluate(() => window.danceResetDisplayTimer());
    const t0 = Date.now();
    await page.waitForTimeout(60000);
    const s = await page.evaluate(() => ({
      ...window.danceStats(), heap: performance.memory ? performance.memory.usedJSHeapSize : 0,
    }));
    const inRate = ((s.framesReceived - prevFrames) * 1000) / (Date.now() - t0);
    prevFrames = s.framesReceived;
    const d = s.display;
    totals.frames += d.frames; totals.sumMs += d.meanMs * d.frames;
    totals.maxMs = Math.max(totals.maxMs, d.maxMs); totals.hitches += d.hitches;
    console.log(`${String(m).padStart(6)} | ${d.fps.toFixed(1).padStart(11)} | ${d.maxMs.toFixed(0).padStart(17)} | ` +
      `${String(d.hitches).padStart(7)} | ${inRate.toFixed(1).padStart(11)} | ` +
      `${String(s.underruns - prevUnderruns).padStart(9)} | ${(s.heap / 1e6).toFixed(1).padStart(7)} | ` +
      `${loadavg()[0].toFixed(1).padStart(7)}`);
    prevUnderruns = s.underruns;
  }
  console.log(`total: ${totals.frames} display frames, mean ${(1000 * totals.frames / totals.sumMs).toFixed(1)} fps, ` +
    `worst interval ${totals.maxMs.toFixed(0)} ms, ${totals.hitches} hitches, console errors ${errors.length}`);
  for (const e of errors.slice(0, 5)) console.log(`  ${e}`);
} finally {
  await browser.close();
  await server.stop();
  rmSync(work, { recursive: true, force: true });
}
