// Builds a Hall table from samples taken at known positions (a calibration sweep
// with a reference). Each grid node gets a local linear fit of the samples within
// one grid step on either side, weighted by a triangle: the Hall output is steep
// (about 1.9 mV/um), so a plain average of a bin would smear it.
#pragma once

#include <string>
#include <vector>

#include "hall_table.hpp"
#include "motor.hpp"
#include "sample.hpp"

namespace ve::core {

class TableBuilder {
 public:
  /// Grid over the whole travel at pitch / points_per_pitch, as nominal_hall_table.
  explicit TableBuilder(const MotorConfig& motor, int points_per_pitch = 256);

  /// Adds one sample at reference position x_m. Missing sensors are skipped.
  void add(double x_m, const RawSample& sample);

  /// Fits every node. Fails (returns false, says why) when nodes lack samples:
  /// the sweep did not cover the travel. With allow_missing, such nodes are NaN
  /// instead (for partial tables that are only compared, never used).
  bool finish(HallTable& out, std::string& error, bool allow_missing = false) const;

  /// Fraction of grid nodes that have enough samples so far (for progress).
  double coverage() const;

 private:
  struct Sums {
    double w = 0, wd = 0, wdd = 0, wy = 0, wdy = 0;
    int n = 0;
  };
  HallTable grid_;  // geometry only
  std::vector<Sums> sums_;  // sensors * points
};

}  // namespace ve::core
