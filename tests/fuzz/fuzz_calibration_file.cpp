// Fuzz target: calibration files (corrupt, truncated, foreign ones must be refused, never crash).
#include <cstdint>

#include "config/calibration_file.hpp"
#include "fuzz_util.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string& path = ve::fuzz::scratch_file("x.cal.yaml");
  if (!ve::fuzz::write_input(path, data, size)) return 0;
  ve::core::MotorConfig motor;
  motor.travel_m = 0.02;  // small tables keep each run fast
  const auto r = ve::config::load_calibration_file(path, motor);
  if (r.ok()) {
    // A file that loads must be usable: evaluate the table across and beyond its grid.
    const auto& t = r.calibration.table;
    for (int s = 0; s < t.sensors; ++s)
      for (double x = t.start_m - 0.01; x <= t.end_m() + 0.01; x += 0.001) (void)t.value(s, x);
  }
  return 0;
}
