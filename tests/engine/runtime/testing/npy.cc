#include "tests/engine/runtime/testing/npy.h"

#include <cstring>
#include <fstream>
#include <iterator>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "absl/strings/strip.h"

namespace dance::engine::testing {

absl::StatusOr<NpyArray> ReadNpy(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  if (!f) return absl::NotFoundError(absl::StrCat("cannot open ", path));
  std::vector<char> bytes((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  if (bytes.size() < 12 || std::memcmp(bytes.data(), "\x93NUMPY", 6) != 0) {
    return absl::InvalidArgumentError(absl::StrCat(path, ": not .npy"));
  }
  const int major = bytes[6];
  size_t header_len, pos;
  if (major == 1) {
    header_len = static_cast<uint8_t>(bytes[8]) | static_cast<uint8_t>(bytes[9]) << 8;
    pos = 10;
  } else {
    header_len = 0;
    for (int i = 0; i < 4; ++i) header_len |= static_cast<size_t>(static_cast<uint8_t>(bytes[8 + i])) << (8 * i);
    pos = 12;
  }
  const std::string header(bytes.data() + pos, header_len);
  pos += header_len;
  const bool is_f4 = header.find("'<f4'") != std::string::npos;
  const bool is_i4 = header.find("'<i4'") != std::string::npos;
  if (!is_f4 && !is_i4) return absl::InvalidArgumentError(absl::StrCat(path, ": dtype not <f4/<i4: ", header));
  if (header.find("'fortran_order': False") == std::string::npos) {
    return absl::InvalidArgumentError(absl::StrCat(path, ": Fortran order"));
  }
  const size_t open = header.find("'shape': (");
  const size_t close = header.find(')', open);
  NpyArray a;
  int64_t count = 1;
  for (absl::string_view part :
       absl::StrSplit(header.substr(open + 10, close - open - 10), ',', absl::SkipWhitespace())) {
    int64_t d;
    if (!absl::SimpleAtoi(absl::StripAsciiWhitespace(part), &d)) return absl::InvalidArgumentError("bad shape");
    a.shape.push_back(d);
    count *= d;
  }
  if (bytes.size() - pos < static_cast<size_t>(count) * 4) return absl::DataLossError(absl::StrCat(path, ": short"));
  a.data.resize(count);
  if (is_f4) {
    std::memcpy(a.data.data(), bytes.data() + pos, count * 4);
  } else {
    for (int64_t i = 0; i < count; ++i) {
      int32_t v;
      std::memcpy(&v, bytes.data() + pos + 4 * i, 4);
      a.data[i] = static_cast<float>(v);
    }
  }
  return a;
}

}  // namespace dance::engine::testing
