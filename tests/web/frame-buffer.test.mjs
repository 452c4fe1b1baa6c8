// Unit tests of the page's frame interpolation and playout clock (node --test).
import assert from 'node:assert/strict';
import test from 'node:test';
import { FrameBuffer, slerpWxyz } from '../../web/src/frame-buffer.js';
import { ArrivalPlayoutClock } from '../../web/src/playout-clock.js';

function frame(index, x, angle) {
  const positions = new Array(72).fill(0).map((_, i) => (i % 3 === 0 ? x : i / 100));
  const rotations = [];
  for (let j = 0; j < 24; ++j) rotations.push(Math.cos(angle / 2), 0, Math.sin(angle / 2), 0);  // about Y
  return { type: 'frame', index, time_ms: (index * 1000) / 30, positions, rotations };
}

test('FrameBuffer interpolates positions linearly and rotations by slerp', () => {
  const fb = new FrameBuffer();
  fb.push(frame(0, 0, 0));
  fb.push(frame(1, 1, Math.PI / 2));
  const p = fb.sample(1000 / 120);  // a quarter of the way
  assert.ok(Math.abs(p.positions[0] - 0.25) < 1e-6);
  assert.ok(Math.abs(p.positions[1] - 0.01) < 1e-6);
  const angle = 2 * Math.atan2(p.rotations[2], p.rotations[0]);
  assert.ok(Math.abs(angle - Math.PI / 8) < 1e-5, `slerp angle ${angle}`);
  assert.equal(fb.underruns, 0);
});

test('FrameBuffer holds the ends and counts underruns only past the last frame period', () => {
  const fb = new FrameBuffer();
  assert.equal(fb.sample(0), null);
  fb.push(frame(3, 2, 0));
  fb.push(frame(4, 3, 0));
  assert.equal(fb.sample(0).positions[0], 2);
  assert.equal(fb.sample(4 * 1000 / 30 + 10).positions[0], 3);
  assert.equal(fb.underruns, 0);
  fb.sample(6 * 1000 / 30);
  assert.equal(fb.underruns, 1);
});

test('FrameBuffer ignores repeated or old frames and bad messages, and drops old frames', () => {
  const fb = new FrameBuffer({ keepMs: 1000 });
  assert.equal(fb.push(frame(5, 0, 0)), true);
  assert.equal(fb.push(frame(5, 0, 0)), false);
  assert.equal(fb.push(frame(4, 0, 0)), false);
  assert.equal(fb.push({ index: 6, time_ms: 200, positions: [1, 2] }), false);
  for (let i = 6; i < 300; ++i) fb.push(frame(i, i, 0));
  fb.sample(299 * 1000 / 30);
  assert.ok(fb.length <= 32 && fb.length >= 30, `${fb.length} frames kept`);
});

test('slerp takes the short way round and keeps unit length', () => {
  const a = [1, 0, 0, 0];
  const b = [-Math.cos(0.1), 0, -Math.sin(0.1), 0];  // the same rotation as +0.2 rad, negated
  const out = [0, 0, 0, 0];
  slerpWxyz(a, b, 0, 0.5, out);
  assert.ok(Math.abs(Math.hypot(...out) - 1) < 1e-9);
  assert.ok(Math.abs(2 * Math.atan2(out[2], out[0]) - 0.1) < 1e-9);
});

test('ArrivalPlayoutClock plays bursts of 4 frames smoothly, one buffer behind the earliest arrival', () => {
  let now = 1000;
  const clock = new ArrivalPlayoutClock({ bufferMs: 150, now: () => now });
  const fb = new FrameBuffer();
  let shown = -Infinity;
  const arrival = (step) => 1000 + step * 133.33 + (step % 3) * 20;  // bursts with up to 40 ms jitter
  for (let step = 0; step < 60; ++step) {
    now = arrival(step);
    for (let k = 0; k < 4; ++k) {
      const f = frame(4 * step + k, 0, 0);
      fb.push(f);
      clock.onFrame(f.time_ms);
    }
    while (now + 16 < arrival(step + 1)) {  // display refreshes at ~60 Hz until the next burst
      now += 16;
      const t = clock.nowMs();
      assert.ok(t >= shown, 'the clock never runs backwards');
      shown = t;
      fb.sample(t);
    }
  }
  assert.equal(fb.underruns, 0);
});
