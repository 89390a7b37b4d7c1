// What a test's SDO client got back from the node (CiA 301): the value uploaded, or
// the abort code. Shared by the unit tests' master and the VM test's master.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace ve::test {

struct SdoResult {
  bool ok = false;
  std::uint32_t abort = 0;  ///< abort code, 0 if none
  std::vector<std::uint8_t> data;
  /// The first four bytes, little-endian (CANopen's byte order).
  std::uint32_t u32() const {
    std::uint32_t v = 0;
    for (std::size_t i = 0; i < data.size() && i < 4; ++i) v |= static_cast<std::uint32_t>(data[i]) << (8 * i);
    return v;
  }
  std::string text() const { return std::string(data.begin(), data.end()); }
};

}  // namespace ve::test
