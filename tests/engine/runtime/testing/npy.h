// Minimal .npy (format 1.0/2.0, little-endian float32 / int32, C order) reader for golden tests.
#ifndef DANCE_TESTS_ENGINE_RUNTIME_TESTING_NPY_H_
#define DANCE_TESTS_ENGINE_RUNTIME_TESTING_NPY_H_

#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/statusor.h"

namespace dance::engine::testing {

struct NpyArray {
  std::vector<int64_t> shape;
  std::vector<float> data;  // int32 arrays are converted to float (exact below 2^24)
  int64_t size() const { return static_cast<int64_t>(data.size()); }
};

absl::StatusOr<NpyArray> ReadNpy(const std::string& path);

}  // namespace dance::engine::testing

#endif  // DANCE_TESTS_ENGINE_RUNTIME_TESTING_NPY_H_
