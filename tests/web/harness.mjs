// Shared pieces of the browser tests: a real dance-server on free ports, Debian's Chromium through
// playwright-core, and a pixel comparison of screenshots.
//
// Environment:
//   DANCE_BUILD_DIR   build tree holding bin/dance-server (default /work/main/build, then <repo>/build)
//   DANCE_MODEL       weights for the server (default <repo>/models/test-tiny.dncw)
//   DANCE_SERVER_URL  use an already running server instead of starting one (for debugging the page)
//   CHROMIUM          browser binary (default /usr/bin/chromium)

import { spawn } from 'node:child_process';
import { existsSync, mkdtempSync, rmSync } from 'node:fs';
import { createRequire } from 'node:module';
import { createServer } from 'node:net';
import { tmpdir } from 'node:os';
import { join, resolve } from 'node:path';
import { fileURLToPath } from 'node:url';

export const repo = resolve(fileURLToPath(new URL('../..', import.meta.url)));
// playwright-core is a dependency of web/ (npm ci there), not of this folder.
const { chromium } = createRequire(join(repo, 'web/package.json'))('playwright-core');

/** A TCP port nobody listens on right now. */
export function freePort() {
  return new Promise((res, rej) => {
    const s = createServer();
    s.on('error', rej);
    s.listen(0, '127.0.0.1', () => {
      const { port } = s.address();
      s.close(() => res(port));
    });
  });
}

function buildDir() {
  if (process.env.DANCE_BUILD_DIR) return process.env.DANCE_BUILD_DIR;
  for (const d of ['/work/main/build', join(repo, 'build')]) if (existsSync(join(d, 'bin/dance-server'))) return d;
  return join(repo, 'build');
}

async function waitHealthy(url, child, log, timeoutMs = 60000) {
  const deadline = Date.now() + timeoutMs;
  while (Date.now() < deadline) {
    if (child && child.exitCode !== null) {
      throw new Error(`dance-server exited with ${child.exitCode}:\n${log.join('')}`);
    }
    try {
      const res = await fetch(new URL('healthz', url));
      if (res.ok) return;
    } catch { /* not listening yet */ }
    await new Promise((r) => setTimeout(r, 200));
  }
  throw new Error(`dance-server not healthy at ${url} after ${timeoutMs} ms:\n${log.join('')}`);
}

/**
 * Starts dance-server on free ports with the test model and web/dist as the web root (the diffusion
 * editor only when `editorModel` or DANCE_EDITOR_MODEL names one).
 * Resolves to {url, stop(), log}; stop() ends the process (SIGTERM, then SIGKILL after 5 s).
 */
export async function startServer({ editorModel = process.env.DANCE_EDITOR_MODEL || 'off' } = {}) {
  if (process.env.DANCE_SERVER_URL) {
    const url = process.env.DANCE_SERVER_URL.replace(/\/?$/, '/');
    await waitHealthy(url, null, []);
    return { url, stop: async () => {}, log: [] };
  }
  const binary = join(buildDir(), 'bin/dance-server');
  if (!existsSync(binary)) throw new Error(`no ${binary}: build the project or set DANCE_BUILD_DIR`);
  const model = process.env.DANCE_MODEL || join(repo, 'models/test-tiny.dncw');
  const webRoot = join(repo, 'web/dist');
  if (!existsSync(join(webRoot, 'index.html'))) throw new Error(`no ${webRoot}/index.html: npm run build in web/`);
  const [grpcPort, httpPort] = [await freePort(), await freePort()];
  // Abseil flags: names with underscores.
  const args = [`--model=${model}`, `--port=${grpcPort}`, `--http_port=${httpPort}`, `--web_root=${webRoot}`,
    `--editor_model=${editorModel}`];
  const child = spawn(binary, args, { stdio: ['ignore', 'pipe', 'pipe'] });
  const log = [];
  const keep = (d) => { log.push(d.toString()); if (log.length > 200) log.shift(); };
  child.stdout.on('data', keep);
  child.stderr.on('data', keep);
  const url = `http://127.0.0.1:${httpPort}/`;
  await waitHealthy(url, child, log);
  const stop = () => new Promise((res) => {
    if (child.exitCode !== null) { res(); return; }
    const kill = setTimeout(() => child.kill('SIGKILL'), 5000);
    child.once('exit', () => { clearTimeout(kill); res(); });
    child.kill('SIGTERM');
  });
  return { url, stop, log, args };
}

/** Launches headless Chromium with a fresh profile; `extraArgs` are added to the fixed flags. */
export async function launchBrowser(extraArgs = []) {
  const profile = mkdtempSync(join(tmpdir(), 'dance-chromium-'));
  const context = await chromium.launchPersistentContext(profile, {
    executablePath: process.env.CHROMIUM || '/usr/bin/chromium',
    headless: true,
    viewport: { width: 1280, height: 720 },
    acceptDownloads: true,
    args: [
      '--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
      '--disable-background-networking', '--disable-component-update', '--disable-sync',
      '--autoplay-policy=no-user-gesture-required', ...extraArgs,
    ],
  });
  const close = async () => {
    await context.close();
    rmSync(profile, { recursive: true, force: true });
  };
  return { context, close };
}

/**
 * Collects console errors and uncaught exceptions of `page` into an array (the tests assert it is empty).
 */
export function collectErrors(page) {
  const errors = [];
  page.on('console', (m) => { if (m.type() === 'error') errors.push(`console: ${m.text()}`); });
  page.on('pageerror', (e) => errors.push(`pageerror: ${e.message}`));
  return errors;
}

/**
 * Opens `url` in a new page of `browser` and waits for the app; resolves to {page, errors} (errors as
 * collectErrors).
 */
export async function openPage(browser, url) {
  const page = await browser.context.newPage();
  const errors = collectErrors(page);
  await page.goto(url);
  await page.waitForFunction(() => typeof window.danceStats === 'function');
  return { page, errors };
}

/**
 * Fraction of pixels that differ (any channel by more than `threshold` of 255) between two PNG buffers of
 * the same size, decoded by the browser in `page`.
 */
export async function pixelDifference(page, pngA, pngB, threshold = 24) {
  return page.evaluate(async ([a, b, th]) => {
    const decode = async (b64) => {
      const blob = await (await fetch(`data:image/png;base64,${b64}`)).blob();
      const bitmap = await createImageBitmap(blob);
      const canvas = new OffscreenCanvas(bitmap.width, bitmap.height);
      const ctx = canvas.getContext('2d');
      ctx.drawImage(bitmap, 0, 0);
      return ctx.getImageData(0, 0, bitmap.width, bitmap.height);
    };
    const [x, y] = [await decode(a), await decode(b)];
    if (x.width !== y.width || x.height !== y.height) return 1;
    let differing = 0;
    for (let i = 0; i < x.data.length; i += 4) {
      if (Math.abs(x.data[i] - y.data[i]) > th || Math.abs(x.data[i + 1] - y.data[i + 1]) > th ||
          Math.abs(x.data[i + 2] - y.data[i + 2]) > th) ++differing;
    }
    return differing / (x.width * x.height);
  }, [pngA.toString('base64'), pngB.toString('base64'), threshold]);
}

/** Polls `fn` (async or not) until it returns a truthy value; rejects with `what` after `timeoutMs`. */
export async function waitFor(fn, what, timeoutMs = 20000, intervalMs = 100) {
  const deadline = Date.now() + timeoutMs;
  let last;
  while (Date.now() < deadline) {
    last = await fn();
    if (last) return last;
    await new Promise((r) => setTimeout(r, intervalMs));
  }
  throw new Error(`timed out waiting for ${what} (last: ${JSON.stringify(last)})`);
}
