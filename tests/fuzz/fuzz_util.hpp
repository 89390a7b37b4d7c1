// Shared by the fuzz targets: the parsers under test read files, so each input
// is written to a private temporary file first.
#pragma once

#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>

namespace ve::fuzz {

/// A file in a private directory made once per process; rewritten per input.
inline const std::string& scratch_file(const char* name) {
  static std::string dir = [] {
    char tmpl[] = "/tmp/ve-fuzz-XXXXXX";
    const char* d = mkdtemp(tmpl);
    return std::string(d ? d : "/tmp");
  }();
  static std::string path;
  path = dir + "/" + name;
  return path;
}

inline bool write_input(const std::string& path, const std::uint8_t* data, std::size_t size) {
  std::FILE* f = std::fopen(path.c_str(), "wb");
  if (f == nullptr) return false;
  const bool ok = std::fwrite(data, 1, size, f) == size;
  return std::fclose(f) == 0 && ok;
}

}  // namespace ve::fuzz
