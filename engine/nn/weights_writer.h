// Writer for `.dncw` files (the exact inverse of WeightsFile::Parse). The training side writes the real
// files in Python; this writer exists so C++ tests can build small models and corrupted copies.
//
// Usage:
//   WeightsWriter w(metadata_json);
//   w.Add("seq.norm_f.weight", {256}, values);
//   w.Add("seq.head.upper", {512, 256}, head_values, WeightsWriter::Dtype::kF16);  // stored as binary16
//   std::vector<uint8_t> bytes = w.Serialize();
//   absl::Status s = w.WriteFile("/tmp/x.dncw");
//
// Thread safety: none (a builder).
#ifndef DANCE_ENGINE_NN_WEIGHTS_WRITER_H_
#define DANCE_ENGINE_NN_WEIGHTS_WRITER_H_

#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "nlohmann/json.hpp"

namespace dance::engine {

class WeightsWriter {
 public:
  explicit WeightsWriter(nlohmann::json metadata) : metadata_(std::move(metadata)) {}

  // How a tensor is stored: "f32" as given, or "f16" rounded to nearest even binary16 (FloatToHalf;
  // |x| >= 65520 becomes Inf and NaN stays NaN, which the reader refuses: tests write such files on purpose).
  enum class Dtype { kF32, kF16 };

  // Adds a tensor; values.size() must equal product(shape).
  void Add(const std::string& name, const std::vector<int64_t>& shape, const std::vector<float>& values,
           Dtype dtype = Dtype::kF32);

  // Removes the tensor called `name` if present (tests build damaged variants this way).
  void Remove(const std::string& name);
  nlohmann::json& metadata() { return metadata_; }

  std::vector<uint8_t> Serialize() const;
  absl::Status WriteFile(const std::string& path) const;

 private:
  struct Entry {
    std::string name;
    std::vector<int64_t> shape;
    std::vector<float> values;
    Dtype dtype;
  };
  nlohmann::json metadata_;
  std::vector<Entry> entries_;
};

}  // namespace dance::engine

#endif  // DANCE_ENGINE_NN_WEIGHTS_WRITER_H_
