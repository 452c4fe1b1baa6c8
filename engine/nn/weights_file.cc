#include "engine/nn/weights_file.h"

#include <cmath>
#include <cstring>
#include <fstream>
#include <iterator>

#include "absl/status/status.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "engine/nn/crc32.h"
#include "engine/nn/half.h"

namespace dance::engine {
namespace {

constexpr size_t kAlignment = 64;
constexpr size_t kPreludeBytes = 16;  // magic, version, header length
constexpr uint64_t kMaxHeaderBytes = 64ull << 20;

uint32_t ReadU32(const uint8_t* p) {
  return static_cast<uint32_t>(p[0]) | static_cast<uint32_t>(p[1]) << 8 |
         static_cast<uint32_t>(p[2]) << 16 | static_cast<uint32_t>(p[3]) << 24;
}

uint64_t ReadU64(const uint8_t* p) {
  return static_cast<uint64_t>(ReadU32(p)) | static_cast<uint64_t>(ReadU32(p + 4)) << 32;
}

size_t RoundUp(size_t n, size_t a) { return (n + a - 1) / a * a; }

absl::Status Corrupt(const std::string& what) {
  return absl::DataLossError(absl::StrCat("weights file: ", what));
}

// The tensor dtypes a file may store (docs/weights-format.md); both are read into float32.
struct StoredDtype {
  const char* name;
  uint64_t bytes;  // per value
};
constexpr StoredDtype kDtypes[] = {{"f32", 4}, {"f16", 2}};

const StoredDtype* FindDtype(const std::string& name) {
  for (const StoredDtype& d : kDtypes) {
    if (name == d.name) return &d;
  }
  return nullptr;
}

std::string SupportedDtypes() {  // for error messages: "f32", "f16"
  std::vector<std::string> quoted;
  for (const StoredDtype& d : kDtypes) quoted.push_back(absl::StrCat("\"", d.name, "\""));
  return absl::StrJoin(quoted, ", ");
}

// Parses one entry of the header's "tensors" list and copies its data out of `data` (data section).
absl::StatusOr<Tensor> ReadTensor(const nlohmann::json& entry, absl::Span<const uint8_t> data) {
  if (!entry.is_object() || !entry.contains("name") || !entry["name"].is_string()) {
    return Corrupt("a tensor entry has no string \"name\"");
  }
  Tensor t;
  t.name = entry["name"].get<std::string>();
  const std::string where = absl::StrCat("tensor '", t.name, "': ");
  for (const char* key : {"dtype", "shape", "offset", "nbytes", "crc32"}) {
    if (!entry.contains(key)) return Corrupt(absl::StrCat(where, "missing \"", key, "\""));
  }
  const StoredDtype* dtype = nullptr;
  if (entry["dtype"].is_string()) dtype = FindDtype(entry["dtype"].get<std::string>());
  if (dtype == nullptr) {
    return absl::InvalidArgumentError(absl::StrCat("weights file: ", where, "dtype ", entry["dtype"].dump(),
                                                   " unsupported (supported: ", SupportedDtypes(), ")"));
  }
  if (!entry["shape"].is_array()) return Corrupt(absl::StrCat(where, "shape is not a list"));
  uint64_t count = 1;
  for (const auto& dim : entry["shape"]) {
    if (!dim.is_number_integer() || dim.get<int64_t>() < 0 || dim.get<int64_t>() > (1ll << 31)) {
      return Corrupt(absl::StrCat(where, "bad dimension ", dim.dump()));
    }
    t.shape.push_back(dim.get<int64_t>());
    const uint64_t d = static_cast<uint64_t>(t.shape.back());
    if (d != 0 && count > (1ull << 34) / d) return Corrupt(absl::StrCat(where, "absurd size"));  // no wrap
    count *= d;
  }
  for (const char* key : {"offset", "nbytes", "crc32"}) {
    if (!entry[key].is_number_unsigned()) return Corrupt(absl::StrCat(where, "\"", key, "\" is not unsigned"));
  }
  const uint64_t offset = entry["offset"].get<uint64_t>();
  const uint64_t nbytes = entry["nbytes"].get<uint64_t>();
  if (nbytes != count * dtype->bytes) {
    return Corrupt(absl::StrCat(where, "nbytes ", nbytes, " != ", dtype->bytes, " * product", ShapeToString(t.shape),
                                " (dtype ", dtype->name, ")"));
  }
  if (offset % kAlignment != 0) return Corrupt(absl::StrCat(where, "offset ", offset, " not 64-aligned"));
  if (offset > data.size() || nbytes > data.size() - offset) {
    return Corrupt(absl::StrCat(where, "bytes [", offset, ", ", offset + nbytes, ") outside the data section (",
                                data.size(), " bytes)"));
  }
  absl::Span<const uint8_t> bytes = data.subspan(offset, nbytes);
  if (Crc32(bytes) != entry["crc32"].get<uint64_t>()) return Corrupt(absl::StrCat(where, "CRC-32 mismatch"));
  t.data.resize(count);
  if (dtype->bytes == 4) {
    std::memcpy(t.data.data(), bytes.data(), nbytes);  // little-endian host assumed (x86-64, aarch64)
  } else {
    // f16: widened once here, so the in-memory Tensor (and everything that computes with it) stays float32.
    for (size_t i = 0; i < t.data.size(); ++i) {
      t.data[i] = HalfToFloat(static_cast<uint16_t>(bytes[2 * i] | bytes[2 * i + 1] << 8));
    }
  }
  for (size_t i = 0; i < t.data.size(); ++i) {
    if (!std::isfinite(t.data[i])) {
      return absl::InvalidArgumentError(
          absl::StrCat("weights file: ", where, "value ", i, " is ", t.data[i], " (NaN/Inf not allowed)"));
    }
  }
  return t;
}

}  // namespace

absl::Status ReadMetadataInt(const nlohmann::json& obj, const std::string& where, const char* key, int lo, int hi,
                             int* out) {
  if (!obj.contains(key) || !obj[key].is_number_integer()) {
    return absl::InvalidArgumentError(absl::StrCat("weights metadata: ", where, ".", key, " missing"));
  }
  const int64_t v = obj[key].get<int64_t>();
  if (v < lo || v > hi) {
    return absl::InvalidArgumentError(
        absl::StrCat("weights metadata: ", where, ".", key, " = ", v, " outside [", lo, ", ", hi, "]"));
  }
  *out = static_cast<int>(v);
  return absl::OkStatus();
}

std::string ShapeToString(const std::vector<int64_t>& shape) {
  return absl::StrCat("[", absl::StrJoin(shape, ", "), "]");
}

absl::StatusOr<WeightsFile> WeightsFile::Load(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError(absl::StrCat("cannot open weights file '", path, "'"));
  std::vector<uint8_t> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (in.bad()) return absl::DataLossError(absl::StrCat("error reading weights file '", path, "'"));
  absl::StatusOr<WeightsFile> file = Parse(bytes);
  if (!file.ok()) {
    return absl::Status(file.status().code(), absl::StrCat(file.status().message(), " (", path, ")"));
  }
  return file;
}

absl::StatusOr<WeightsFile> WeightsFile::Parse(absl::Span<const uint8_t> bytes) {
  if (bytes.size() < kPreludeBytes + 4) {
    return Corrupt(absl::StrCat("truncated: ", bytes.size(), " bytes is shorter than the fixed prelude"));
  }
  if (std::memcmp(bytes.data(), kWeightsMagic, 4) != 0) {
    return absl::InvalidArgumentError("weights file: bad magic (not a DNCW file)");
  }
  const uint32_t version = ReadU32(bytes.data() + 4);
  if (version != kWeightsVersion) {
    return absl::InvalidArgumentError(
        absl::StrCat("weights file: format version ", version, " unsupported (this engine reads ", kWeightsVersion,
                     ")"));
  }
  const uint64_t header_len = ReadU64(bytes.data() + 8);
  if (header_len > kMaxHeaderBytes || kPreludeBytes + header_len + 4 > bytes.size()) {
    return Corrupt(absl::StrCat("truncated: header length ", header_len, " exceeds the file (", bytes.size(),
                                " bytes)"));
  }
  const size_t data_start = RoundUp(kPreludeBytes + header_len, kAlignment);
  if (data_start + 4 > bytes.size()) return Corrupt("truncated: no data section");
  const size_t crc_pos = bytes.size() - 4;
  const uint32_t stored_crc = ReadU32(bytes.data() + crc_pos);
  if (Crc32(bytes.subspan(0, crc_pos)) != stored_crc) {
    return Corrupt("file CRC-32 mismatch (truncated or corrupted)");
  }

  nlohmann::json header = nlohmann::json::parse(bytes.begin() + kPreludeBytes,
                                                bytes.begin() + kPreludeBytes + header_len, nullptr,
                                                /*allow_exceptions=*/false);
  if (header.is_discarded() || !header.is_object()) return Corrupt("header is not a JSON object");
  if (header.value("format", "") != "dance-weights") return Corrupt("header \"format\" is not \"dance-weights\"");
  if (!header.contains("version") || header["version"] != kWeightsVersion) {
    return absl::InvalidArgumentError("weights file: header version is not 1");
  }
  if (!header.contains("tensors") || !header["tensors"].is_array()) return Corrupt("header has no \"tensors\" list");

  WeightsFile file;
  if (header.contains("metadata")) {
    if (!header["metadata"].is_object()) return Corrupt("\"metadata\" is not an object");
    file.metadata_ = header["metadata"];
  } else {
    file.metadata_ = nlohmann::json::object();
  }
  absl::Span<const uint8_t> data = bytes.subspan(data_start, crc_pos - data_start);
  for (const auto& entry : header["tensors"]) {
    absl::StatusOr<Tensor> t = ReadTensor(entry, data);
    if (!t.ok()) return t.status();
    std::string name = t->name;
    if (!file.tensors_.emplace(name, *std::move(t)).second) {
      return Corrupt(absl::StrCat("tensor '", name, "' appears twice"));
    }
  }
  return file;
}

const Tensor* WeightsFile::Find(const std::string& name) const {
  auto it = tensors_.find(name);
  return it == tensors_.end() ? nullptr : &it->second;
}

absl::StatusOr<const Tensor*> WeightsFile::Get(const std::string& name, const std::vector<int64_t>& shape) const {
  const Tensor* t = Find(name);
  if (t == nullptr) return absl::NotFoundError(absl::StrCat("weights file: missing tensor '", name, "'"));
  if (t->shape != shape) {
    return absl::InvalidArgumentError(absl::StrCat("weights file: tensor '", name, "' has shape ",
                                                   ShapeToString(t->shape), ", the model needs ",
                                                   ShapeToString(shape)));
  }
  return t;
}

}  // namespace dance::engine
