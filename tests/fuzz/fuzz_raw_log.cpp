// Fuzz target: raw log v1 (bad headers, non-monotonic time, wrong column counts, garbage).
#include <cstdint>

#include "fuzz_util.hpp"
#include "replay/raw_log.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string& path = ve::fuzz::scratch_file("log.csv");
  if (!ve::fuzz::write_input(path, data, size)) return 0;
  ve::replay::RawLogReader reader;
  if (!reader.open(path)) return 0;
  ve::replay::RawLogRow row;
  for (int i = 0; i < 100000; ++i) {
    const auto n = reader.next(row);
    if (n == ve::replay::RawLogReader::Next::end) break;
  }
  return 0;
}
