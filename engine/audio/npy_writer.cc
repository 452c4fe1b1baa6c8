#include "engine/audio/npy_writer.h"

#include <cstdio>
#include <cstring>
#include <fstream>
#include <iterator>

#include "absl/strings/match.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"

namespace dance::engine::audio {

absl::Status WriteNpyFloat32(const std::string& path, absl::Span<const float> data, int64_t rows,
                             int64_t cols) {
  if (rows < 0 || cols < 0 || static_cast<int64_t>(data.size()) != rows * cols) {
    return absl::InvalidArgumentError(
        absl::StrCat("npy: data has ", data.size(), " values, shape is (", rows, ", ", cols, ")"));
  }
  std::string header =
      absl::StrCat("{'descr': '<f4', 'fortran_order': False, 'shape': (", rows, ", ", cols, "), }");
  // Magic (6) + version (2) + header length (2) + header + '\n' must be a multiple of 64.
  const size_t unpadded = 10 + header.size() + 1;
  header.append((64 - unpadded % 64) % 64, ' ');
  header.push_back('\n');
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (!out)
    return absl::UnavailableError(absl::StrCat("npy: cannot open '", path, "' for writing"));
  const char magic[8] = {'\x93', 'N', 'U', 'M', 'P', 'Y', 1, 0};
  out.write(magic, 8);
  const uint16_t len = static_cast<uint16_t>(header.size());
  const char len_bytes[2] = {static_cast<char>(len & 0xff), static_cast<char>(len >> 8)};
  out.write(len_bytes, 2);
  out.write(header.data(), static_cast<std::streamsize>(header.size()));
  // The engine only targets little-endian hosts (x86-64, aarch64).
  out.write(reinterpret_cast<const char*>(data.data()),
            static_cast<std::streamsize>(data.size() * sizeof(float)));
  out.close();
  if (!out) return absl::UnavailableError(absl::StrCat("npy: write to '", path, "' failed"));
  return absl::OkStatus();
}

absl::StatusOr<NpyArray> ReadNpyFloat32(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError(absl::StrCat("npy: cannot open '", path, "'"));
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (bytes.size() < 10 || bytes.compare(0, 6, "\x93NUMPY") != 0 || bytes[6] != 1) {
    return absl::InvalidArgumentError(
        absl::StrCat("npy: '", path, "' is not a version 1 .npy file"));
  }
  const size_t header_len = static_cast<uint8_t>(bytes[8]) | (static_cast<uint8_t>(bytes[9]) << 8);
  if (bytes.size() < 10 + header_len) return absl::InvalidArgumentError("npy: truncated header");
  const std::string header = bytes.substr(10, header_len);
  if (!absl::StrContains(header, "'descr': '<f4'") ||
      !absl::StrContains(header, "'fortran_order': False")) {
    return absl::InvalidArgumentError(
        "npy: only little-endian float32 C-order arrays are supported");
  }
  const size_t open = header.find("'shape': (");
  const size_t close = header.find(')', open);
  if (open == std::string::npos || close == std::string::npos) {
    return absl::InvalidArgumentError("npy: no shape in header");
  }
  const std::string shape = header.substr(open + 10, close - open - 10);
  const size_t comma = shape.find(',');
  NpyArray array;
  if (comma == std::string::npos || !absl::SimpleAtoi(shape.substr(0, comma), &array.rows) ||
      !absl::SimpleAtoi(shape.substr(comma + 1), &array.cols)) {
    return absl::InvalidArgumentError(absl::StrCat("npy: expected a 2-D shape, got (", shape, ")"));
  }
  if (array.rows < 0 || array.cols < 0 ||
      (array.cols > 0 && array.rows > static_cast<int64_t>(bytes.size()) / array.cols)) {
    return absl::InvalidArgumentError(absl::StrCat("npy: implausible shape (", shape, ")"));
  }
  const size_t count = static_cast<size_t>(array.rows * array.cols);
  if (bytes.size() != 10 + header_len + count * sizeof(float)) {
    return absl::InvalidArgumentError("npy: data size does not match shape");
  }
  array.data.resize(count);
  if (count > 0)
    std::memcpy(array.data.data(), bytes.data() + 10 + header_len, count * sizeof(float));
  return array;
}

}  // namespace dance::engine::audio
