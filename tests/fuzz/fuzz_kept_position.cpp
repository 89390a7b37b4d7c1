// Fuzz target: the position kept at a clean shutdown (homing.state_file). Whatever
// the file holds, it is refused with a reason or read whole; never a crash, and the
// file is removed either way (a kept position is used once).
#include <unistd.h>

#include <cmath>
#include <cstdint>
#include <cstdlib>

#include "config/kept_position.hpp"
#include "fuzz_util.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string& path = ve::fuzz::scratch_file("x.kept.yaml");
  if (!ve::fuzz::write_input(path, data, size)) return 0;
  ve::config::KeptPosition k;
  std::string why;
  const auto r = ve::config::take_kept_position(path, "x", "sim-12mm", "0123456789abcdef", k, why);
  if (::access(path.c_str(), F_OK) == 0) std::abort();  // must be gone
  if (r == ve::config::KeptRead::ok && (!std::isfinite(k.position_m) || k.axis != "x")) std::abort();
  if (r == ve::config::KeptRead::refused && why.empty()) std::abort();
  return 0;
}
