// libFuzzer target for the decode + feature path.
//
// Byte 0 selects the mode:
//   even: the rest is an encoded file (any format libsndfile knows); it is decoded with a bounded
//   length
//         and streamed through the front end in chunks whose sizes come from byte 1.
//   odd:  bytes 1-4 declare a sample rate, byte 5 a channel count (both may be invalid), the rest
//   is raw
//         float32 PCM (any bit pattern: NaN, Inf, denormals) pushed through the front end.
// Invariants checked: no crash or sanitizer report; every emitted feature and PRE value is finite.
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <vector>

#include "engine/audio/audio_front_end.h"
#include "engine/audio/decoder.h"

namespace {

using dance::engine::audio::AudioFrontEnd;
using dance::engine::audio::AudioFrontEndOptions;
using dance::engine::audio::FeatureFrames;

void CheckFinite(AudioFrontEnd* fe) {
  FeatureFrames frames;
  fe->PopFrames(&frames);
  for (float v : frames.features) {
    if (!std::isfinite(v)) std::abort();
  }
  for (float v : frames.pre) {
    if (!std::isfinite(v)) std::abort();
  }
}

void Stream(AudioFrontEnd* fe, const float* samples, size_t count, size_t chunk_frames) {
  const size_t ch = static_cast<size_t>(fe->options().channels);
  const size_t frames = count / ch;
  for (size_t start = 0; start < frames; start += chunk_frames) {
    const size_t n = std::min(chunk_frames, frames - start);
    if (!fe->PushFloat(absl::MakeConstSpan(samples + start * ch, n * ch)).ok()) std::abort();
    CheckFinite(fe);
  }
  if (!fe->Flush().ok()) std::abort();
  CheckFinite(fe);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 2) return 0;
  if ((data[0] & 1) == 0) {
    // At most 20 s at the highest rate, so one input stays fast.
    auto audio = dance::engine::audio::DecodeAudioMemory(absl::MakeConstSpan(data + 2, size - 2),
                                                         "fuzz", 96000 * 20);
    if (!audio.ok()) return 0;
    auto fe = AudioFrontEnd::Create({audio->sample_rate, audio->channels});
    if (!fe.ok()) std::abort();  // the decoder only returns supported rates and channel counts
    Stream(fe->get(), audio->samples.data(), audio->samples.size(), 1 + data[1] * 37);
    return 0;
  }
  if (size < 6) return 0;
  int32_t rate;
  std::memcpy(&rate, data + 1, 4);
  AudioFrontEndOptions options{rate, static_cast<int>(data[5] % 12)};
  auto fe = AudioFrontEnd::Create(options);
  if (!fe.ok()) return 0;  // invalid rate or channel count: a clean error is the expected outcome
  std::vector<float> pcm((size - 6) / sizeof(float));
  if (!pcm.empty()) std::memcpy(pcm.data(), data + 6, pcm.size() * sizeof(float));
  pcm.resize(pcm.size() - pcm.size() % options.channels);
  Stream(fe->get(), pcm.data(), pcm.size(), 1 + data[1] * 13);
  return 0;
}
