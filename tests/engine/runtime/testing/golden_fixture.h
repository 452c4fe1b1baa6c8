// Reading golden fixture directories (tests/golden/README.md): an index file naming .npy arrays, written by
// the PyTorch side (training/fixtures.py: index.json; training/diffusion/fixtures.py: sgmd.json), and the
// normalised error the parity tests compare with: max |a - b| / max(1, max |b|).
//
// Usage:
//   for (const auto& dir : GoldenDirs("index.json")) { GoldenFixture g(dir, "index.json"); ... g.Array("x") ... }
#ifndef DANCE_TESTS_ENGINE_RUNTIME_TESTING_GOLDEN_FIXTURE_H_
#define DANCE_TESTS_ENGINE_RUNTIME_TESTING_GOLDEN_FIXTURE_H_

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "tests/engine/runtime/testing/npy.h"

namespace dance::engine::testing {

inline double NormalisedError(const float* a, const float* b, int64_t n) {
  double max_diff = 0.0, max_ref = 0.0;
  for (int64_t i = 0; i < n; ++i) {
    max_diff = std::max(max_diff, std::abs(static_cast<double>(a[i]) - b[i]));
    max_ref = std::max(max_ref, std::abs(static_cast<double>(b[i])));
  }
  return max_diff / std::max(1.0, max_ref);
}

class GoldenFixture {
 public:
  GoldenFixture(std::filesystem::path dir, const std::string& index_file) : dir_(std::move(dir)) {
    std::ifstream f(dir_ / index_file);
    index_ = nlohmann::json::parse(f);
  }
  NpyArray Array(const std::string& name) const {
    absl::StatusOr<NpyArray> a = ReadNpy((dir_ / index_["arrays"][name]["file"].get<std::string>()).string());
    EXPECT_TRUE(a.ok()) << name << ": " << a.status();
    return a.ok() ? *a : NpyArray();
  }
  const nlohmann::json& index() const { return index_; }
  std::string name() const { return dir_.filename().string(); }

 private:
  std::filesystem::path dir_;
  nlohmann::json index_;
};

// The directories of tests/golden (relative to the working directory) that hold `index_file`, sorted.
inline std::vector<std::filesystem::path> GoldenDirs(const std::string& index_file) {
  std::vector<std::filesystem::path> out;
  if (!std::filesystem::exists("tests/golden")) return out;
  for (const auto& e : std::filesystem::directory_iterator("tests/golden")) {
    if (std::filesystem::exists(e.path() / index_file)) out.push_back(e.path());
  }
  std::sort(out.begin(), out.end());
  return out;
}

}  // namespace dance::engine::testing

#endif  // DANCE_TESTS_ENGINE_RUNTIME_TESTING_GOLDEN_FIXTURE_H_
