// Error statistics of an estimate against the truth: what `evaluate`, the
// accuracy tests and the benchmark report. Streaming; no storage per sample.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>

namespace ve::core {

/// RMS, bias (mean), standard deviation and largest magnitude of one error signal.
class ErrorAccumulator {
 public:
  void add(double error) {
    ++n_;
    sum_ += error;
    sum_sq_ += error * error;
    max_abs_ = std::max(max_abs_, std::abs(error));
  }
  std::uint64_t count() const { return n_; }
  double rms() const { return n_ ? std::sqrt(sum_sq_ / n_) : 0.0; }
  double bias() const { return n_ ? sum_ / n_ : 0.0; }
  double std_dev() const {
    if (n_ == 0) return 0.0;
    const double m = bias();
    return std::sqrt(std::max(0.0, sum_sq_ / n_ - m * m));
  }
  double max_abs() const { return max_abs_; }

 private:
  std::uint64_t n_ = 0;
  double sum_ = 0.0, sum_sq_ = 0.0, max_abs_ = 0.0;
};

/// Position and velocity errors, and how often the truth lay within +-2 sigma.
struct EstimateErrors {
  ErrorAccumulator position_m;
  ErrorAccumulator velocity_mps;
  std::uint64_t position_within_2sigma = 0;
  std::uint64_t velocity_within_2sigma = 0;
  std::uint64_t not_valid = 0;  ///< samples in the window whose status was not VALID
  double position_var_sum_m2 = 0.0;  ///< sum of the published position variances

  void add(double position_error_m, double position_std_m, double velocity_error_mps, double velocity_std_mps,
           bool valid) {
    position_m.add(position_error_m);
    velocity_mps.add(velocity_error_mps);
    position_var_sum_m2 += position_std_m * position_std_m;
    if (std::abs(position_error_m) <= 2.0 * position_std_m) ++position_within_2sigma;
    if (std::abs(velocity_error_mps) <= 2.0 * velocity_std_mps) ++velocity_within_2sigma;
    if (!valid) ++not_valid;
  }
  double position_coverage() const {
    return position_m.count() ? static_cast<double>(position_within_2sigma) / position_m.count() : 0.0;
  }
  /// The mean of the published position variances [m^2].
  double position_std_m2_mean() const {
    return position_m.count() ? position_var_sum_m2 / static_cast<double>(position_m.count()) : 0.0;
  }
  double velocity_coverage() const {
    return velocity_mps.count() ? static_cast<double>(velocity_within_2sigma) / velocity_mps.count() : 0.0;
  }
};

}  // namespace ve::core
