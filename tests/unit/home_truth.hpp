// Home (the position 0 of a calibration without a reference) located on the
// simulator's own sensor 0 and magnet track, in the simulator's frame: the same
// definition as identify_without_reference's (the mean of sensor 0's rising and
// then falling crossing of its mid level, 0.5 (min + max) over the travel),
// applied to the noiseless Hall model as the ADC reads it (clamped to its range:
// a table's min and max are the rails where the sensor saturates). The calibration only says which half-wave
// (where it found it, to tens of um, from the sweep's start, which is the
// simulator's 0); where in it is the simulator's.
#pragma once

#include <algorithm>
#include <cmath>

#include "core/motor.hpp"
#include "core/self_calibration.hpp"
#include "sim/sim_config.hpp"
#include "sim/sim_source.hpp"

namespace ve::test {

inline double home_truth_m(const ve::core::MotorConfig& motor, const ve::sim::SimConfig& sim_cfg,
                           const ve::core::SelfCalibrationReport& rep) {
  const ve::sim::SimSource source(motor, sim_cfg);
  struct Clamped {
    const ve::sim::SimSource& s;
    double lo, hi;
    double hall_voltage_noiseless(int i, double x) const { return std::clamp(s.hall_voltage_noiseless(i, x), lo, hi); }
  } sim{source, motor.adc.min_v, motor.adc.max_v};
  const double pitch = motor.magnet_pitch_m;
  double lo = 1e9, hi = -1e9;
  for (double x = 0.0; x <= motor.travel_m; x += 5e-6) {
    const double v = sim.hall_voltage_noiseless(0, x);
    lo = std::min(lo, v), hi = std::max(hi, v);
  }
  const double mid = 0.5 * (lo + hi);
  // The crossing of the mid level in the given direction nearest to `near`.
  auto crossing = [&](double near, bool rising) {
    const double step = 1e-6;
    double best = std::nan(""), best_d = 1e9;
    for (double x = near - 0.25 * pitch; x < near + 0.25 * pitch; x += step) {
      double a = sim.hall_voltage_noiseless(0, x) - mid, b = sim.hall_voltage_noiseless(0, x + step) - mid;
      if ((a < 0) == (b < 0) || (a < 0) != rising) continue;
      double l = x, h = x + step;  // bisection to well below a nanometre
      for (int k = 0; k < 40; ++k) {
        const double m = 0.5 * (l + h);
        ((sim.hall_voltage_noiseless(0, m) - mid < 0) == (a < 0) ? l : h) = m;
      }
      const double c = 0.5 * (l + h);
      if (std::abs(c - near) < best_d) best_d = std::abs(c - near), best = c;
    }
    return best;
  };
  const double rising = crossing(rep.home_from_sweep_start_m + rep.home_rising_m, true);
  const double falling = crossing(rep.home_from_sweep_start_m + rep.home_falling_m, false);
  return 0.5 * (rising + falling);
}

}  // namespace ve::test
