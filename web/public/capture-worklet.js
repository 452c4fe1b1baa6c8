// AudioWorklet processor: posts each 128-frame render quantum of its input, downmixed to mono, to the page
// (which batches and streams it to /ws/perform). Runs on the audio rendering thread; never allocates more
// than the one buffer it transfers.
class DanceCapture extends AudioWorkletProcessor {
  process(inputs) {
    const channels = inputs[0];
    if (channels && channels.length > 0 && channels[0].length > 0) {
      const n = channels[0].length;
      const mono = new Float32Array(n);
      for (const ch of channels) for (let i = 0; i < n; ++i) mono[i] += ch[i];
      if (channels.length > 1) for (let i = 0; i < n; ++i) mono[i] /= channels.length;
      this.port.postMessage(mono, [mono.buffer]);
    }
    return true;
  }
}
registerProcessor('dance-capture', DanceCapture);
