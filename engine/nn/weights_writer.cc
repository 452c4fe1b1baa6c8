#include "engine/nn/weights_writer.h"

#include <cstring>
#include <fstream>

#include "absl/strings/str_cat.h"
#include "engine/nn/crc32.h"
#include "engine/nn/half.h"
#include "engine/nn/weights_file.h"

namespace dance::engine {
namespace {

void PutU32(std::vector<uint8_t>& out, uint32_t v) {
  for (int i = 0; i < 4; ++i) out.push_back(static_cast<uint8_t>(v >> (8 * i)));
}

void PadTo64(std::vector<uint8_t>& out, size_t base) {
  while ((out.size() - base) % 64 != 0) out.push_back(0);
}

}  // namespace

void WeightsWriter::Add(const std::string& name, const std::vector<int64_t>& shape,
                        const std::vector<float>& values, Dtype dtype) {
  entries_.push_back({name, shape, values, dtype});
}

void WeightsWriter::Remove(const std::string& name) {
  std::erase_if(entries_, [&name](const Entry& e) { return e.name == name; });
}

std::vector<uint8_t> WeightsWriter::Serialize() const {
  std::vector<uint8_t> data;
  nlohmann::json tensors = nlohmann::json::array();
  for (const Entry& e : entries_) {
    PadTo64(data, 0);
    const size_t offset = data.size();
    const bool f16 = e.dtype == Dtype::kF16;
    const size_t nbytes = e.values.size() * (f16 ? 2 : sizeof(float));
    data.resize(offset + nbytes);
    if (f16) {
      for (size_t i = 0; i < e.values.size(); ++i) {
        const uint16_t h = FloatToHalf(e.values[i]);
        data[offset + 2 * i] = static_cast<uint8_t>(h);
        data[offset + 2 * i + 1] = static_cast<uint8_t>(h >> 8);
      }
    } else {
      std::memcpy(data.data() + offset, e.values.data(), nbytes);
    }
    tensors.push_back({{"name", e.name},
                       {"dtype", f16 ? "f16" : "f32"},
                       {"shape", e.shape},
                       {"offset", offset},
                       {"nbytes", nbytes},
                       {"crc32", Crc32(absl::MakeConstSpan(data.data() + offset, nbytes))}});
  }
  const nlohmann::json header = {
      {"format", "dance-weights"}, {"version", kWeightsVersion}, {"metadata", metadata_}, {"tensors", tensors}};
  const std::string text = header.dump();
  std::vector<uint8_t> out(kWeightsMagic, kWeightsMagic + 4);
  PutU32(out, kWeightsVersion);
  const uint64_t len = text.size();
  PutU32(out, static_cast<uint32_t>(len));
  PutU32(out, static_cast<uint32_t>(len >> 32));
  out.insert(out.end(), text.begin(), text.end());
  PadTo64(out, 0);
  out.insert(out.end(), data.begin(), data.end());
  PutU32(out, Crc32(out));
  return out;
}

absl::Status WeightsWriter::WriteFile(const std::string& path) const {
  const std::vector<uint8_t> bytes = Serialize();
  std::ofstream f(path, std::ios::binary | std::ios::trunc);
  if (!f) return absl::PermissionDeniedError(absl::StrCat("cannot write '", path, "'"));
  f.write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
  if (!f) return absl::DataLossError(absl::StrCat("error writing '", path, "'"));
  return absl::OkStatus();
}

}  // namespace dance::engine
