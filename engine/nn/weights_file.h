// Reader for the `.dncw` weights file, version 1 (layout in docs/architecture.md, names in
// docs/weights-format.md).
//
// Load validates everything a corrupt or foreign file can get wrong, and returns a Status naming the
// problem instead of crashing: magic, format version, header length and JSON, every tensor's dtype, shape,
// nbytes and bounds, each tensor's CRC-32, the whole file's CRC-32, and that no value is NaN or Inf.
// Tensors are stored as "f32" (IEEE binary32) or "f16" (IEEE binary16, widened exactly to float32 here);
// in memory every Tensor is float32 whatever its stored dtype, and an unknown dtype is InvalidArgument.
// Whether a tensor the model needs exists with the right shape is checked by the model builder through
// `Get(name, shape)`.
//
// Usage:
//   absl::StatusOr<WeightsFile> w = WeightsFile::Load("models/test-tiny.dncw");
//   if (!w.ok()) return w.status();
//   absl::StatusOr<const Tensor*> t = w->Get("seq.head_upper.weight", {512, 256});
//
// Ownership: a WeightsFile owns its tensors' data. Thread safety: immutable after Load; safe to read from
// any number of threads.
#ifndef DANCE_ENGINE_NN_WEIGHTS_FILE_H_
#define DANCE_ENGINE_NN_WEIGHTS_FILE_H_

#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "absl/types/span.h"
#include "nlohmann/json.hpp"

namespace dance::engine {

inline constexpr char kWeightsMagic[4] = {'D', 'N', 'C', 'W'};
inline constexpr uint32_t kWeightsVersion = 1;

// One named float32 tensor, row-major (the last dimension varies fastest); "f16" tensors of the file are
// held here as their exact float32 values.
struct Tensor {
  std::string name;
  std::vector<int64_t> shape;
  std::vector<float> data;  // product(shape) values

  int64_t size() const { return static_cast<int64_t>(data.size()); }
};

class WeightsFile {
 public:
  // Reads and validates the file at `path`.
  static absl::StatusOr<WeightsFile> Load(const std::string& path);
  // Validates an in-memory copy of a file (the bytes are not retained).
  static absl::StatusOr<WeightsFile> Parse(absl::Span<const uint8_t> bytes);

  // The header's "metadata" object (model id, hyperparameters, skeleton, styles, vq ops, ...).
  const nlohmann::json& metadata() const { return metadata_; }

  // The tensor called `name`, or nullptr.
  const Tensor* Find(const std::string& name) const;
  // The tensor called `name`, which must have exactly `shape`; NotFound / InvalidArgument otherwise.
  absl::StatusOr<const Tensor*> Get(const std::string& name, const std::vector<int64_t>& shape) const;

  const std::map<std::string, Tensor>& tensors() const { return tensors_; }

 private:
  nlohmann::json metadata_;
  std::map<std::string, Tensor> tensors_;
};

// "[a, b, c]" for error messages.
std::string ShapeToString(const std::vector<int64_t>& shape);

// Reads the integer obj[key] (the metadata object `where`, e.g. "hyperparameters") into *out:
// InvalidArgument "weights metadata: where.key missing" / "... = v outside [lo, hi]".
absl::Status ReadMetadataInt(const nlohmann::json& obj, const std::string& where, const char* key, int lo, int hi,
                             int* out);

}  // namespace dance::engine

#endif  // DANCE_ENGINE_NN_WEIGHTS_FILE_H_
