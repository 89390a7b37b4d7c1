// Fuzz target: calibration files (corrupt, truncated, foreign or unusable ones must be
// refused, never crash). A file that loads has passed the semantic checks, so what
// they promise is asserted here: a grid step that fits the pitch, a grid covering the
// travel, finite values within the ADC range widened by its span, and a table the
// estimator can interpolate anywhere.
#include <cmath>
#include <cstdint>
#include <cstdlib>

#include "config/calibration_file.hpp"
#include "fuzz_util.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string& path = ve::fuzz::scratch_file("x.cal.yaml");
  if (!ve::fuzz::write_input(path, data, size)) return 0;
  ve::core::MotorConfig motor;
  motor.travel_m = 0.02;  // small tables keep each run fast
  const auto r = ve::config::load_calibration_file(path, motor);
  if (!r.ok()) {
    for (const auto& e : r.errors)
      if (e.file != path || e.message.empty()) std::abort();  // every refusal names the file and says why
    return 0;
  }
  const auto& t = r.calibration.table;
  if (!t.valid() || t.sensors != motor.hall.count) std::abort();
  if (!(t.step_m >= motor.magnet_pitch_m / 4096.0 && t.step_m <= motor.magnet_pitch_m / 8.0)) std::abort();
  if (!(t.start_m <= 1e-9 && t.end_m() >= motor.travel_m - 1e-9)) std::abort();
  const double span = motor.adc.max_v - motor.adc.min_v;
  for (const double v : t.v)
    if (!std::isfinite(v) || v < motor.adc.min_v - span || v > motor.adc.max_v + span) std::abort();
  // Usable: evaluate the table across and beyond its grid.
  for (int s = 0; s < t.sensors; ++s)
    for (double x = t.start_m - 0.01; x <= t.end_m() + 0.01; x += 0.001) {
      double v = 0.0, slope = 0.0;
      t.evaluate(s, x, v, slope);
      if (!std::isfinite(v) || !std::isfinite(slope)) std::abort();
    }
  return 0;
}
