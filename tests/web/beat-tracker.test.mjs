// Unit test of the page's causal beat tracker on synthetic drum patterns (node --test).
import assert from 'node:assert/strict';
import test from 'node:test';
import { BeatTracker } from '../../web/src/beat-tracker.js';

const kRate = 24000;

/** A kick (decaying 60 Hz) every beat plus an off-beat hat (noise burst), `seconds` long. */
function drums(bpm, seconds, offsetS = 0.1) {
  const out = new Float32Array(Math.round(seconds * kRate));
  const period = 60 / bpm;
  let seed = 1;
  const noise = () => ((seed = (seed * 1103515245 + 12345) % 2147483648) / 2147483648) * 2 - 1;
  for (let t = offsetS; t < seconds; t += period) {
    const s = Math.round(t * kRate);
    for (let i = 0; i < 0.15 * kRate && s + i < out.length; ++i) {
      out[s + i] += 0.8 * Math.sin(2 * Math.PI * 60 * i / kRate) * Math.exp(-i / (0.04 * kRate));
    }
    const h = Math.round((t + period / 2) * kRate);
    for (let i = 0; i < 0.03 * kRate && h + i < out.length; ++i) {
      out[h + i] += 0.2 * noise() * Math.exp(-i / (0.008 * kRate));
    }
  }
  return out;
}

function track(audio, chunk) {
  const beats = [];
  const tracker = new BeatTracker(kRate, (t) => beats.push(t));
  for (let i = 0; i < audio.length; i += chunk) tracker.push(audio.subarray(i, i + chunk));
  return { beats, bpm: tracker.bpm };
}

for (const bpm of [90, 120, 150]) {
  test(`BeatTracker follows ${bpm} BPM on the kicks`, () => {
    const offset = 0.1;
    const { beats, bpm: found } = track(drums(bpm, 20, offset), 480);
    assert.ok(Math.abs(found - bpm) / bpm < 0.04, `tempo ${found} for ${bpm}`);
    const late = beats.filter((t) => t > 8000);
    assert.ok(late.length > 0.8 * (12 * bpm / 60), `${late.length} beats after 8 s`);
    const period = 60000 / bpm;
    for (const t of late) {
      const phase = ((t - offset * 1000) % period + period) % period;
      const err = Math.min(phase, period - phase);
      assert.ok(err < 40, `beat at ${t.toFixed(0)} ms is ${err.toFixed(0)} ms off the kick`);
    }
    for (let i = 1; i < beats.length; ++i) assert.ok(beats[i] > beats[i - 1] + 0.5 * period);
  });
}

test('BeatTracker is chunking invariant', () => {
  const audio = drums(128, 12);
  assert.deepEqual(track(audio, 128).beats, track(audio, 4801).beats);
});

test('BeatTracker emits nothing on silence', () => {
  assert.equal(track(new Float32Array(kRate * 10), 1000).beats.length, 0);
});
