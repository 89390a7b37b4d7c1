// Block SF: several saturating Hall sensors -> one carriage position with its
// variance. Each sensor is used only where it is out of saturation; there its
// slope is steep, and the fused variance follows from the slopes of the sensors
// that contributed (a sample near a crossing of two steep sensors is worth more
// than one seen by a single sensor near its clamp).
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include "hall_table.hpp"
#include "motor.hpp"
#include "sample.hpp"

namespace ve::core {

struct HallFix {
  bool ok = false;
  double position_m = 0.0;
  double variance_m2 = 0.0;     ///< from the slopes and noise of the sensors used
  int sensors_used = 0;         ///< sensors out of saturation that carried the fix
  double chi2 = 0.0;            ///< sum of squared normalised residuals of the sensors used
  /// The same with the table's own error in each reading (HallArray::add_table_error):
  /// what a healthy sensor may disagree by; equal to chi2 without that error.
  double chi2_table = 0.0;
  std::uint32_t missing_mask = 0;  ///< bit i: sensor i had no sample
  bool out_of_table = false;    ///< the solution ran into an end of the table
  /// Saturated sensors whose table value at the solution is far from the rail they
  /// read: the solution (or that sensor) is wrong. A fix with conflicts is not ok.
  std::uint32_t conflict_mask = 0;
  /// With an adaptation whose common gain is uncertain: the fix's estimate of the
  /// gain every sensor shares, relative to the one the readings were corrected
  /// with, and its posterior variance (0, 0 without).
  double common_gain = 0.0;
  double common_gain_variance = 0.0;
  /// What the sensors' offsets, drifting by their data sheet's spreads, add to
  /// common_gain's variance per kelvin squared of rise [1/K^2]: a drift of one
  /// sensor's offset reads as a change of the gain all share, most where few
  /// sensors are out of saturation (0 without an adaptation).
  double common_gain_offset_var_per_k2 = 0.0;
  /// The part of the fix's error that repeats from sample to sample while the
  /// carriage stands still: the ADC's quantisation, which the sensors' own noise
  /// dithers only partly (variance_m2 counts it as white noise) [m^2].
  double quantisation_m2 = 0.0;
  /// The sum of the squared sensitivities of the position to each sensor's reading
  /// [m^2/V^2]: a reading error common to the table's place (its noise,
  /// SensorModel::table_noise_v) moves the fix by this times its variance.
  double sensitivity_m2_per_v2 = 0.0;
  /// The sensitivities summed with their signs [m/V]: an offset common to every
  /// reading (the coil field's, SensorModel::coil_field_std_v_per_mps2) moves the fix
  /// by this times the offset.
  double offset_sensitivity_m_per_v = 0.0;
  /// The sum over the sensors used of the squared sensitivity of the position to the
  /// sensor's reading times the reading's level about mid [m^2]: independent relative
  /// errors of the sensors' gains, of variance g each, move the fix by this times g.
  double level_sensitivity_m2 = 0.0;
  /// The same sensitivities times the levels, summed with their signs [m]: a relative
  /// error g of the gain every sensor shares moves the fix by this times g (0 where the
  /// fix's own estimate of the common gain takes it up). Both only until a fix has
  /// read the temperature (HallAdaptation::temperature_checked), 0 after.
  double common_level_m = 0.0;
  /// Likewise what the adaptation is still unsure of in the sensors' gains and
  /// offsets beyond its start-up prior (HallAdaptation::combined_variance, with the
  /// sensors' correlations once they are learnt jointly): it repeats
  /// until the carriage has moved a good part of a magnet period [m^2].
  double drift_m2 = 0.0;
};

class HallAdaptation;

class HallArray {
 public:
  HallArray(const MotorConfig& motor, HallTable table);
  /// Adds a noise every fix carries beyond the sensors' own (SensorModel::hall_fix_excess_std_m) [m].
  void add_fix_noise(double std_m) { floor_m2_ += std_m * std_m; }
  /// The same excess (std_m [m]) as each sensor's reading carries it, for judging the
  /// sensors only (HallFix::chi2_table; never the fix, its weights or its chi2): a table
  /// whose sensors' curves are a few mV apart at some places makes a healthy sensor look
  /// like the odd one out there, and leaving that sensor out of the fix there is still
  /// the better fix. Independent per sensor, a reading error of variance s2 leaves
  /// s2 / sum_i slope_i^2 in the fix, so s2 = std_m^2 times that sum, averaged over the
  /// table's nodes (the sensors between the rails at each).
  void add_table_error(double std_m);
  /// That reading variance [V^2] (0: none).
  double table_error_v2() const { return table_error_v2_; }

  /// Refines a position near `guess_m` (normally the filter's prediction).
  /// Converges when the guess is within about pitch/8 of the truth. No allocation.
  /// `common_mode_v` is removed from every reading first (the coil field's offset).
  /// Only sensors in `use_mask` take part (the others are ignored entirely).
  /// With `adaptation`, each sensor's reading also carries the uncertainty of its
  /// adapted gain and offset: it weighs less in the fix and in its chi-square; and
  /// while the gain all sensors share is uncertain, it is estimated with the
  /// position (a common change of gain is not a position error: the fix's variance
  /// holds what the sensors cannot tell apart).
  HallFix solve(const RawSample& sample, double guess_m, double common_mode_v = 0.0,
                std::uint32_t use_mask = 0xFFu, const HallAdaptation* adaptation = nullptr) const;

  /// Searches [lo_m, hi_m] for the best-matching position (start-up, re-acquisition),
  /// then refines it. Cost grows with the window; use at most a few periods.
  HallFix acquire(const RawSample& sample, double lo_m, double hi_m, double common_mode_v = 0.0,
                  std::uint32_t use_mask = 0xFFu, const HallAdaptation* adaptation = nullptr) const;

  const HallTable& table() const { return table_; }
  double pitch_m() const { return pitch_m_; }

 private:
  bool usable(const RawSample& s, int i, std::uint32_t use_mask) const;
  /// The cubic of every sensor on one grid interval, in the form evaluate_all()
  /// takes it: the coefficients depend on the interval alone, and a solve's
  /// iterations mostly stay on one interval, so it keeps them between its calls.
  struct Cell {
    int k = -1;  ///< the interval [k, k + 1] they are for (-1: none yet)
    std::array<double, kMaxHalls> a3, b2, a, b, c, p1;  ///< 3 a, 2 b, a, b, c, and the knot at k
  };
  /// Every sensor's table value and slope at `x_m` (HallTable::evaluate for sensors
  /// 0 .. sensors_ - 1, the same arithmetic): the grid cell is found once, and the
  /// four knots around it are adjacent in memory for all sensors. `cell` holds the
  /// coefficients of the last interval evaluated; they are worked out again only
  /// when `x_m` is on another one.
  void evaluate_all(double x_m, Cell& cell, std::array<double, kMaxHalls>& value_v,
                    std::array<double, kMaxHalls>& slope_v_per_m) const;

  HallTable table_;
  /// table_.v knot-major: knots_[k * kMaxHalls + s] is sensor s at grid point k
  /// (sensors beyond the table's hold 0).
  std::vector<double> knots_;
  double pitch_m_;
  int sensors_;
  double lo_v_;        ///< readings at or below are saturated low
  double hi_v_;        ///< readings at or above are saturated high
  double weight_;      ///< 1 / per-sensor voltage variance [1/V^2]
  double floor_m2_;    ///< variance floor added to every fix [m^2]
  double table_error_v2_ = 0.0;  ///< add_table_error: per reading, in the chi-square only [V^2]
  /// Variance of a reading's quantisation error that the noise does not average
  /// away (the reading's mean, as a function of the input, still steps) [V^2].
  double quantisation_v2_;
};

}  // namespace ve::core
