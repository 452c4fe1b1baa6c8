// Writes float32 matrices in NumPy's .npy format (version 1.0, little-endian, C order).
//
//   std::vector<float> data(rows * cols);
//   absl::Status s = dance::engine::audio::WriteNpyFloat32("x.npy", data, rows, cols);
//
// Thread-safe (no shared state). Returns InvalidArgument if data.size() != rows * cols, and an
// Internal/NotFound-like error with the path if the file cannot be written.
#ifndef DANCE_ENGINE_AUDIO_NPY_WRITER_H_
#define DANCE_ENGINE_AUDIO_NPY_WRITER_H_

#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/types/span.h"

namespace dance::engine::audio {

// Writes `data` (row-major, rows x cols) as a 2-D float32 array.
absl::Status WriteNpyFloat32(const std::string& path, absl::Span<const float> data, int64_t rows,
                             int64_t cols);

// A 2-D float32 array read back from .npy (tests and tools only; accepts what WriteNpyFloat32
// writes).
struct NpyArray {
  int64_t rows = 0;
  int64_t cols = 0;
  std::vector<float> data;  // (rows, cols), row-major
};
absl::StatusOr<NpyArray> ReadNpyFloat32(const std::string& path);

}  // namespace dance::engine::audio

#endif  // DANCE_ENGINE_AUDIO_NPY_WRITER_H_
