// Calibration with a reference ruler: from recorded samples and the reference
// position of each, identify everything the estimator needs to know about one
// motor and its sensors:
//  - each Hall sensor's output over the whole travel (the table), from slow
//    constant-speed passes in both directions;
//  - the Hall delay: forward and backward passes disagree by 2 v d;
//  - the coil field: a common-mode Hall offset proportional to the acceleration,
//    from fast motion;
//  - the accelerometer's scale, bias and delay, by regression against the
//    reference's own acceleration.
// Pure computation on vectors held in memory; no I/O.
#pragma once

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "hall_table.hpp"
#include "motor.hpp"
#include "sample.hpp"

namespace ve::core {

/// One contiguous recording (uniform sampling, no gaps) with a reference position per sample.
struct ReferenceSegment {
  std::vector<RawSample> samples;
  std::vector<double> reference_m;
};

/// What the identification needs of the motion, and how it judges the result.
struct IdentificationConfig {
  /// Constant-speed samples: |v| in [min, max] and |a| below the limit go into the table.
  double sweep_min_speed_mps = 0.002;
  double sweep_max_speed_mps = 0.1;
  double sweep_max_accel_mps2 = 0.05;
  /// The final table takes every slow sample (|v| up to sweep_max_speed_mps) with
  /// |a| up to this, turnarounds included, corrected for the coil field.
  double table_max_accel_mps2 = 2.0;
  /// Samples with |a| above this identify the coil field and the accelerometer.
  double dynamic_min_accel_mps2 = 1.0;
  /// Fewest such samples for a usable identification (0.25 s at 4 kHz).
  int dynamic_min_samples = 1000;
  /// Half-width of the Savitzky-Golay window that differentiates the reference [samples].
  int derivative_half_window = 20;
  /// Largest accelerometer delay searched [s].
  double max_accel_delay_s = 1e-3;
  int points_per_pitch = 256;
  /// Table nodes this close to an end of the travel that no sample reached take
  /// the values one magnet period inwards instead of failing (calibration without
  /// a reference: its own scale may end the sweep a few um short of the grid) [m].
  double fill_uncovered_ends_m = 0.0;
  /// The verdict's residuals (readings about the table, Hall position in fast motion)
  /// count only positions in [from, to]: without a ruler, where the slow passes made
  /// the reference (the turnarounds beyond are judged apart) [m].
  double judged_from_m = -std::numeric_limits<double>::infinity();
  double judged_to_m = std::numeric_limits<double>::infinity();
  /// The reference in fast motion is independent of the Halls (a ruler). Without
  /// one the self-made reference there is made of these Hall positions, and their
  /// residual against it is reported as a consistency figure, not judged.
  bool fast_reference_independent = true;
  /// false: leave out what neither the table nor the coil field needs: the
  /// accelerometer's delay scan (its scale, bias, delay and fit residual stay at
  /// their ideal values, and the verdict does not judge them), the search for a
  /// frame vibration and the Hall position's residual in fast motion. For a caller
  /// that runs the identification again and again (calibration without a ruler:
  /// once per iteration), fits the accelerometer itself and keeps only the last
  /// result, which it asks for in full; these were most of each run's compute.
  bool fast_motion_report = true;
  /// Search for a frame vibration in the accelerometer: frequency range [Hz], the
  /// stretch of recording used [s], and how far above the spectrum's median (and
  /// above an absolute level) a line must stand to count.
  double vibration_min_hz = 5.0;
  double vibration_max_hz = 500.0;
  double vibration_window_s = 8.0;
  double vibration_min_ratio = 8.0;
  double vibration_min_mps2 = 0.005;
};

/// What the report plots beside the figures: per bin of position over the travel.
struct IdentificationCurves {
  double bin_m = 0.0;                       ///< bin width [m]
  std::vector<double> position_m;           ///< bin centres
  std::vector<double> residual_mv;          ///< RMS of the sweep's readings about the final table; NaN: no data
  std::vector<double> forward_backward_um;  ///< forward minus backward table as a position shift; NaN: no data
};

struct IdentificationReport {
  int sweep_forward_samples = 0;
  int sweep_backward_samples = 0;
  double sweep_speed_mps = 0.0;          ///< mean |v| of the table samples
  double hall_delay_s = 0.0;              ///< from the slow sweep's two directions
  /// The Hall delay the fast motion gives (its Hall positions against the reference,
  /// regressed on velocity) and that estimate's standard error [s]; 0 without fast
  /// motion or without an independent reference. hall_delay_from_fast_motion: it
  /// agreed with the sweep's and the calibration took it.
  double fast_hall_delay_s = 0.0, fast_hall_delay_std_s = 0.0;
  bool hall_delay_from_fast_motion = false;
  double forward_backward_shift_um = 0.0;  ///< forward minus backward table, as a position shift (= 2 v d)
  int dynamic_samples = 0;
  double dynamic_max_accel_mps2 = 0.0;
  double coil_field_v_per_mps2 = 0.0;
  /// Its standard error from the fit (NaN: not known) [V per m/s^2].
  double coil_field_std_v_per_mps2 = std::numeric_limits<double>::quiet_NaN();
  double accel_scale = 1.0;
  double accel_bias_mps2 = 0.0;
  double accel_delay_s = 0.0;
  /// Its standard error from the fit (NaN: not known) [s].
  double accel_delay_std_s = std::numeric_limits<double>::quiet_NaN();
  double accel_fit_residual_mps2 = 0.0;  ///< RMS of the accelerometer after the fit
  bool frame_accelerometer_used = false;
  double vibration_hz = 0.0;             ///< frame vibration found in the accelerometer; 0 = none
  double vibration_mps2 = 0.0;           ///< its amplitude
  double vibration_floor_mps2 = 0.0;     ///< median of the residual spectrum
  /// The table's own noise at a node (half the forward and backward tables' RMS
  /// difference once the Hall delay's shift is out): SensorModel::table_noise_v [mV].
  double table_noise_mv = 0.0;
  double table_residual_mv = 0.0;        ///< RMS of the readings about the final table (sweep, in range)
  double position_residual_um = 0.0;     ///< RMS of the Hall position about the reference (fast motion, compensated)
  double position_residual_uncompensated_um = 0.0;  ///< the same without delay and coil-field compensation
  /// RMS of the fixes' own σ over the same samples (the sensors' noise and quantisation).
  double position_noise_um = 0.0;
  /// The compensated residual beyond that noise (0 when the residual is within it): what
  /// the delay and coil-field compensation left. The verdict judges this one.
  double position_residual_beyond_noise_um = 0.0;
  bool good = false;
  std::vector<std::string> problems;     ///< why the result is not good, in words a commissioning engineer acts on
  IdentificationCurves curves;           ///< for the report's plots
};

/// The accelerometer's fitted scale and delay judged: a scale outside 0.8..1.2 (wrong
/// sensitivity or axis) or a delay at the end of the range searched is a problem,
/// appended to `problems`.
void judge_accelerometer(double scale, double delay_s, double max_delay_s, std::vector<std::string>& problems);

/// Identifies table and sensor model. False (with `error`) when the recording
/// cannot give a result at all (e.g. the sweep does not cover the travel);
/// otherwise true, with report.good telling whether the result can be trusted.
bool identify_with_reference(const MotorConfig& motor, const std::vector<ReferenceSegment>& segments,
                             const IdentificationConfig& config, Calibration& out, IdentificationReport& report,
                             std::string& error);

/// Linear regression y = slope * x + intercept; false when x does not vary.
struct Regression {
  double sx = 0, sy = 0, sxx = 0, sxy = 0, syy = 0;
  long n = 0;
  void add(double x, double y) {
    sx += x;
    sy += y;
    sxx += x * x;
    sxy += x * y;
    syy += y * y;
    ++n;
  }
  bool solve(double& slope, double& intercept, double& residual_rms) const {
    if (n < 3) return false;
    const double mx = sx / n, my = sy / n;
    const double vxx = sxx / n - mx * mx;
    if (!(vxx > 0.0)) return false;
    const double vxy = sxy / n - mx * my;
    const double vyy = syy / n - my * my;
    slope = vxy / vxx;
    intercept = my - slope * mx;
    residual_rms = std::sqrt(std::max(0.0, vyy - slope * vxy));
    return true;
  }
};

/// Velocity and acceleration of a uniformly sampled position by a quadratic
/// Savitzky-Golay fit over 2 * half_window + 1 samples; `valid` is false within
/// half a window of the ends.
void differentiate(const std::vector<double>& x_m, double ts_s, int half_window, std::vector<double>& v_mps,
                   std::vector<double>& a_mps2, std::vector<char>& valid);

}  // namespace ve::core
