#include "engine/audio/decoder.h"

#include <sndfile.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <fstream>
#include <iterator>

#include "absl/status/status.h"
#include "absl/strings/str_cat.h"

namespace dance::engine::audio {
namespace {

// libsndfile virtual I/O over a byte span, so files and memory share one decode path.
struct MemoryFile {
  absl::Span<const uint8_t> bytes;
  sf_count_t position = 0;
};

sf_count_t VioLength(void* user) { return static_cast<MemoryFile*>(user)->bytes.size(); }

sf_count_t VioSeek(sf_count_t offset, int whence, void* user) {
  auto* f = static_cast<MemoryFile*>(user);
  sf_count_t base = 0;
  if (whence == SEEK_CUR) base = f->position;
  if (whence == SEEK_END) base = static_cast<sf_count_t>(f->bytes.size());
  const sf_count_t target = base + offset;
  if (target < 0) return -1;
  f->position = std::min<sf_count_t>(target, static_cast<sf_count_t>(f->bytes.size()));
  return f->position;
}

sf_count_t VioRead(void* ptr, sf_count_t count, void* user) {
  auto* f = static_cast<MemoryFile*>(user);
  const sf_count_t left = static_cast<sf_count_t>(f->bytes.size()) - f->position;
  const sf_count_t n = std::max<sf_count_t>(0, std::min(count, left));
  if (n > 0) std::memcpy(ptr, f->bytes.data() + f->position, static_cast<size_t>(n));
  f->position += n;
  return n;
}

sf_count_t VioWrite(const void*, sf_count_t, void*) { return 0; }
sf_count_t VioTell(void* user) { return static_cast<MemoryFile*>(user)->position; }

}  // namespace

absl::StatusOr<DecodedAudio> DecodeAudioMemory(absl::Span<const uint8_t> bytes,
                                               const std::string& name, int64_t max_frames) {
  if (bytes.empty()) return absl::InvalidArgumentError(absl::StrCat("'", name, "' is empty"));
  MemoryFile file{bytes, 0};
  SF_VIRTUAL_IO vio{VioLength, VioSeek, VioRead, VioWrite, VioTell};
  SF_INFO info;
  std::memset(&info, 0, sizeof(info));
  SNDFILE* sf = sf_open_virtual(&vio, SFM_READ, &info, &file);
  if (sf == nullptr) {
    return absl::InvalidArgumentError(
        absl::StrCat("'", name, "' is not a readable audio file: ", sf_strerror(nullptr)));
  }
  struct Closer {
    SNDFILE* sf;
    ~Closer() { sf_close(sf); }
  } closer{sf};
  if (info.channels < 1 || info.channels > kMaxInputChannels) {
    return absl::InvalidArgumentError(absl::StrCat("'", name, "' has ", info.channels,
                                                   " channels; supported: 1..", kMaxInputChannels));
  }
  if (info.samplerate < kMinInputRate || info.samplerate > kMaxInputRate) {
    return absl::InvalidArgumentError(absl::StrCat("'", name, "' has sample rate ", info.samplerate,
                                                   " Hz; supported: ", kMinInputRate, "..",
                                                   kMaxInputRate, " Hz"));
  }
  DecodedAudio audio;
  audio.sample_rate = info.samplerate;
  audio.channels = info.channels;
  // Read in blocks until EOF: frame counts in headers can lie (truncated files, streamed OGG/MP3).
  constexpr sf_count_t kBlockFrames = 16384;
  std::vector<float> block(static_cast<size_t>(kBlockFrames * info.channels));
  int64_t total = 0;
  while (true) {
    const sf_count_t got = sf_readf_float(sf, block.data(), kBlockFrames);
    if (got <= 0) break;
    if (total + got > max_frames || (total + got) * info.channels > kMaxDecodedSamples) {
      return absl::InvalidArgumentError(
          absl::StrCat("'", name, "' is longer than the decoding limit (", max_frames, " frames, ",
                       kMaxDecodedSamples, " samples); stream it instead"));
    }
    audio.samples.insert(audio.samples.end(), block.begin(), block.begin() + got * info.channels);
    total += got;
  }
  if (total == 0) {
    return absl::InvalidArgumentError(
        absl::StrCat("'", name, "' contains no audio frames (", sf_strerror(sf), ")"));
  }
  for (float& x : audio.samples) {
    if (!std::isfinite(x)) x = 0.0f;
  }
  return audio;
}

absl::StatusOr<DecodedAudio> DecodeAudioFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError(absl::StrCat("cannot open audio file '", path, "'"));
  std::vector<uint8_t> bytes((std::istreambuf_iterator<char>(in)),
                             std::istreambuf_iterator<char>());
  return DecodeAudioMemory(bytes, path);
}

}  // namespace dance::engine::audio
