// Thermal calibration: each Hall sensor's own gain and offset temperature
// coefficients, measured from a second recording of the motor some kelvin away
// from a calibration, fitted against that calibration's table.
//
// Why: a sensor's offset drifts by its own coefficient (a few tenths of a mV per
// kelvin, different for every sensor). While the carriage moves, the array's
// redundancy learns it (HallAdaptation); where it stands, no redundancy can tell it
// from a position, and at 10 K from calibration that is several um. Measured once,
// at commissioning, the coefficients let the estimator follow the drift wherever
// the rise is known: reported by the sensor node, or read from the common gain
// every fix sees (the magnets' remanence and the sensors' mean sensitivity).
//
// Model, per sensor i, as HallAdaptation's: y_i = c + m + delta_i + g_i (T_i(x) - m),
// T_i the calibration's table, m the zero-field output, c the coil field's common
// mode, g_i = (1 + G)(1 + gamma_i) with G the gain all sensors share (the geometric
// mean of the g_i) and gamma_i the sensor's own. With a ruler, x is the ruler's
// (at the Halls' instant) and each sensor's (delta_i, g_i) a linear least-squares
// fit. Without one, x comes from the array itself, its readings corrected by the fit
// so far, and every sensor's (delta_i, g_i) is fitted together in one Gauss-Newton
// step per round with each sample's position error a nuisance (over many magnet
// periods an offset or gain change cannot mimic a shift of the position, whose effect
// changes sign with the sensor's slope). The recording is placed on the table first:
// readings corrected by each sensor's quartiles against its table, then an anchor
// sample per recorded segment scored in every period of the table over several
// magnets, chosen again in the second round.
//
// The rise: the node's temperature against the calibration's, when both were
// reported (the common gain per kelvin is then measured too); otherwise the common
// gain read through the data sheet's coefficients, the kelvin the estimator reads
// the same way while running. The coefficients are the changes over the rise.
// Free of I/O.
#pragma once

#include <array>
#include <string>
#include <vector>

#include "hall_table.hpp"
#include "identification.hpp"
#include "motor.hpp"

namespace ve::core {

struct ThermalCalibrationConfig {
  /// A recording closer to the calibration than this says too little [K].
  double min_rise_k = 5.0;
  /// Samples with a larger acceleration (the coil field's common mode) are left out [m/s^2].
  double max_accel_mps2 = 0.5;
  /// How far a real sensor's drift may be from linear over a rise, as a share of
  /// what its coefficient moves it by: the coefficients' uncertainty is at least this.
  double linearity_rel_std = 0.1;
  /// Fewer usable samples of a sensor than this: its coefficients stay the data
  /// sheet's (0, with its spread).
  int min_samples = 200;
  /// Without a ruler: rounds of (positions from the corrected array, fit).
  int rounds = 4;
};

struct ThermalCalibrationReport {
  double rise_k = 0.0;
  bool rise_reported = false;  ///< the node's temperature (else the common gain's reading)
  double common_gain = 0.0;    ///< G over the rise
  int sensors_fitted = 0;
  std::array<double, kMaxHalls> gain_change{}, offset_change_v{};
  std::array<double, kMaxHalls> residual_v{};  ///< each sensor's readings about the fit, RMS
  std::array<int, kMaxHalls> samples{};
  /// Without a ruler: how far the positions moved in the last round, RMS [m].
  double last_round_shift_m = 0.0;
  std::vector<std::string> notes;
};

/// Fits the coefficients of `base` (a calibration of `motor`) from `recording`, the
/// motor at another temperature moving over the calibrated stretch (a calibration
/// run will do); reference_m is used where finite (a ruler), else the positions come
/// from the array. On success `out` is base.model with thermal_known and the
/// coefficients set. False with `error` when the recording cannot give them.
bool fit_thermal_coefficients(const MotorConfig& motor, const Calibration& base,
                              const std::vector<ReferenceSegment>& recording, const ThermalCalibrationConfig& config,
                              SensorModel& out, ThermalCalibrationReport& report, std::string& error);

}  // namespace ve::core
