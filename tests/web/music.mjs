// Deterministic test music for the browser tests: drums (kick and hat on the beat) under a simple bass and
// lead line, written as a 16-bit mono WAV file. (A hat off the beat, even quiet, is the stronger onset for
// log-spectral-flux trackers, the engine's and librosa's alike, which then put the beat on it.)
import { writeFileSync } from 'node:fs';

/** Renders `seconds` of music at `bpm` into a Float32Array at `rate`. */
export function renderMusic({ seconds = 20, bpm = 120, rate = 24000 } = {}) {
  const out = new Float32Array(Math.round(seconds * rate));
  const beat = 60 / bpm;
  let seed = 7;
  const noise = () => ((seed = (seed * 1103515245 + 12345) % 2147483648) / 2147483648) * 2 - 1;
  const notes = [220, 262, 330, 294, 247, 330, 392, 349];
  for (let k = 0; k * beat < seconds; ++k) {
    const t = k * beat;
    const s = Math.round(t * rate);
    for (let i = 0; i < 0.2 * rate && s + i < out.length; ++i) {
      const f = 50 + 60 * Math.exp(-i / (0.02 * rate));  // pitch-dropping kick
      out[s + i] += 0.7 * Math.sin(2 * Math.PI * f * i / rate) * Math.exp(-i / (0.06 * rate));
    }
    for (let i = 0; i < 0.04 * rate && s + i < out.length; ++i) {
      out[s + i] += 0.1 * noise() * Math.exp(-i / (0.01 * rate));  // a hat with the kick
    }
    const f0 = notes[k % notes.length];
    for (let i = 0; i < beat * rate && s + i < out.length; ++i) {
      const env = Math.min(1, i / (0.01 * rate)) * Math.exp(-i / (0.3 * rate));
      out[s + i] += 0.12 * env * (Math.sin(2 * Math.PI * f0 * i / rate) +
                                  0.5 * Math.sin(2 * Math.PI * (f0 / 2) * i / rate));
    }
  }
  return out;
}

/** Writes mono float samples as a 16-bit PCM WAV file. */
export function writeWav(path, samples, rate) {
  const data = Buffer.alloc(samples.length * 2);
  for (let i = 0; i < samples.length; ++i) {
    data.writeInt16LE(Math.round(Math.max(-1, Math.min(1, samples[i])) * 32767), 2 * i);
  }
  const header = Buffer.alloc(44);
  header.write('RIFF', 0);
  header.writeUInt32LE(36 + data.length, 4);
  header.write('WAVEfmt ', 8);
  header.writeUInt32LE(16, 16);
  header.writeUInt16LE(1, 20);         // PCM
  header.writeUInt16LE(1, 22);         // mono
  header.writeUInt32LE(rate, 24);
  header.writeUInt32LE(rate * 2, 28);  // byte rate
  header.writeUInt16LE(2, 32);         // block align
  header.writeUInt16LE(16, 34);        // bits
  header.write('data', 36);
  header.writeUInt32LE(data.length, 40);
  writeFileSync(path, Buffer.concat([header, data]));
}
