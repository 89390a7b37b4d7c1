// Online adaptation of the Hall sensors to slow change (temperature, ageing):
// each sensor's gain about its zero-field output and its offset, tracked while
// running from the redundancy of the array, without recalibration.
//
// Model: a sensor reads y_i = c + m_i + delta_i + (1 + G) (1 + gamma_i) (T_i(x) - m_i),
// where T_i is its calibrated table, m_i its zero-field output (the motor file's
// offset_v; an error in it is taken up by delta_i), c the coil field's common
// mode, G the change of the gain every sensor shares (the magnets' field: the
// remanence falls by about 0.12 %/K; and the sensors' common sensitivity, about
// 0.1 %/K), gamma_i what is left of sensor i's own gain change, and delta_i the
// change of its offset (a few mV over 10 K).
//
// The common gain G is the larger part (about 2 % over 10 K, against a spread of a
// few tenths of a percent between sensors) and moves every reading the same way,
// which a position error does not: every Hall fix estimates it with the position
// (HallArray::solve, from its prior common_gain_variance()), and update_common()
// takes that estimate in. Until it is known, the fix's variance carries it.
//
// Estimation: per sensor a two-state Kalman filter (gamma_i, delta_i as random
// walks) on the residual of its reading against the table at the filter's
// predicted position; the regressor T_i(x) - m_i changes sign over every magnet
// period, so gain and offset separate as the carriage moves (at standstill they
// are taken up together, which is what matters there). Sensor by sensor, each
// learns against the others' drift not learnt yet (taken out as a shift of the
// position), which is harmless while the drift stays within the calibration's
// prior; once the motor is found a kelvin or more from its calibration
// temperature, every sensor's gain and offset are learnt together in one
// covariance, with the sample's position error as a nuisance (joint_update): what
// the array cannot tell from a shift is then held as a correlation between the
// sensors, and the fix's variance (HallArray::solve) takes it with its
// correlations instead of sensor by sensor. The common gain stays the fixes' to
// learn; the joint update considers its uncertainty and keeps its covariance with
// every sensor's gain and offset (a Schmidt consider state), so that what a shift
// and a common gain together explain is not learnt twice. A CUSUM of each sensor's
// normalised residual catches a change faster than the random walk allows and
// re-opens that sensor's covariance, so the parameters follow within a few tens of
// samples. Gains and offsets are bounded: a sensor that needs more than
// any temperature explains (a dead sensor "needs" gamma = -1) is not followed
// but reported (beyond_limits), and the pipeline's health check judges it.
// Fixed size; nothing allocates per sample.
#pragma once

#include <algorithm>
#include <array>
#include <cstdint>

#include "hall_table.hpp"
#include "motor.hpp"
#include "sample.hpp"

namespace ve::core {

class HallAdaptation {
 public:
  /// A sample counts as a new place once the carriage has moved this share of a
  /// magnet period since the last one (the `share` the updates take).
  static constexpr double kNewPlaceShareOfPitch = 1.0 / 200.0;
  /// `model`, when given, may hold each sensor's own temperature coefficients from
  /// a thermal calibration (SensorModel::thermal_known): the sensors then follow a
  /// change of temperature by them instead of only widening by the data sheet's spread.
  HallAdaptation(const MotorConfig& motor, double ts_s, const SensorModel* model = nullptr);

  /// The readings corrected to the calibration's conditions: out = in with each
  /// Hall reading mapped back through its gain and offset (rail readings, which
  /// carry no position, are left as read).
  void correct(const RawSample& in, double common_mode_v, RawSample& out) const;

  /// Takes in a Hall fix's estimate of the common gain: `relative_change` of the
  /// gain the correction assumed, known to variance `variance` (the fix's
  /// posterior, which already holds common_gain_variance() as its prior).
  /// `share` (0..1) is how much of a new fix's information this one carries: fixes
  /// taken where the last ones were repeat their errors (see update()).
  void update_common(double relative_change, double variance, double share = 1.0);

  /// The motor is `delta_k` warmer than at calibration (reported by the sensor
  /// node). The first call sets what the data sheet's coefficients predict: the
  /// common gain, its uncertainty (the coefficients' own), and how far each sensor's
  /// gain and offset may have moved; later calls move the common gain by the
  /// predicted change and widen the uncertainties by what the change allows.
  void temperature(double delta_k);

  /// Without a temperature from the sensor node: a Hall fix's estimate of the common
  /// gain (`relative_change` of the gain the correction assumed, its variance). The
  /// common gain is mostly the magnets' and the sensors' temperature coefficients
  /// (common_tc), so its average over the last fraction of a second says how far the
  /// motor is from its calibration temperature, and with it how far each sensor's own
  /// gain and offset may have moved, as temperature() does with a reported one. Taken
  /// from every fix, moving or not: at standstill it is the only witness of a change
  /// of temperature, and what the sensors' drift does there cannot be learnt.
  /// `share` (0..1) is how much of a new place the fix is (update()): fixes where the
  /// carriage stands repeat their errors, and the thermometer's reading is then known
  /// no better than one fix's.
  void observe_fix_gain(double relative_change, double variance, double share = 1.0,
                        double offset_var_per_k2 = 0.0);
  /// The data sheet's spread of sensor i's offset temperature coefficient, squared [V^2/K^2].
  double offset_tc_variance(int i) const {
    const double s = offset_tc_std_v_[static_cast<std::size_t>(i)];
    return s * s;
  }

  /// Learns from one sample: `x_m` the position the Halls saw (the filter's
  /// prediction at the Halls' instant); only sensors in `mask` (not this sample's
  /// outlier) and out of saturation take part. What a position error would explain
  /// (each sensor's slope times one shift) is taken out of the residuals first, so
  /// an error of the prediction is not learnt as drift; at least two sensors out
  /// of saturation are needed. Sensors in `learn_only_mask` (judged faulty) learn
  /// from the others but take no part in what the others learn.
  /// `share` (0..1) is how much new information the sample carries: the sensors'
  /// residuals repeat while the carriage stands (the others' drift, taken out as a
  /// shift, leaves its mark in each), so samples taken where the last ones were
  /// count for this much of one taken at a new place, and at standstill the
  /// uncertainty stays what it was instead of shrinking on a repeated error.
  void update(const RawSample& raw, const HallTable& table, double x_m, double common_mode_v, std::uint32_t mask,
              std::uint32_t learn_only_mask = 0, double share = 1.0);

  /// Residual of sensor i's raw reading against the adapted model at x, and the
  /// residual's standard deviation [V].
  double residual(const RawSample& raw, const HallTable& table, int i, double x_m, double common_mode_v,
                  double& std_v) const;

  /// What the thermal coefficients moved the sensors' readings by since the last
  /// call (follow_rise), as the square of the largest change of one reading [V^2],
  /// and resets it: a step of the model, not of the carriage, which the filter
  /// should take in its position, not its velocity.
  double take_moved_v2() {
    const double v = moved_v2_;
    moved_v2_ = 0.0;
    return v;
  }

  bool enabled() const { return enabled_; }
  /// The rise over the calibration the sensors follow by their thermal coefficients
  /// (0 without a thermal calibration, or before the rise is first read) [K].
  double followed_rise_k() const { return followed_k_; }
  /// Whether the estimator knows how far the motor's temperature is from the
  /// calibration's: reported by the node, or read from the fixes' common gain
  /// (observe_fix_gain, after its first average). Until then the sensors' gains and
  /// offsets may have moved by any amount a temperature change explains, which the
  /// published sigma cannot know yet.
  bool temperature_checked() const { return !enabled_ || temperature_known_ || inferred_started_; }
  /// Whether a fix whose common gain came out with variance `common_gain_variance`
  /// is a reading of the thermometer (observe_fix_gain): the gain it returns is known
  /// to at most kInferKnownShare of the start-up prior's variance.
  bool reads_temperature(double common_gain_variance) const {
    return common_gain_variance <= kInferKnownShare * p0_common_;
  }
  /// The variance a change of temperature of `rise_k`, not read, leaves in a fix with
  /// these sensitivities (HallFix::common_level_m, sensitivity_m2_per_v2,
  /// level_sensitivity_m2) [m^2]: the gain all sensors share by the data sheet's
  /// coefficients (known to temperature_coefficient_rel_std), and each sensor's own
  /// gain and offset by their spreads.
  double unread_rise_variance(double rise_k, double common_level_m, double sensitivity_m2_per_v2,
                              double level_sensitivity_m2) const {
    const double common = common_tc_per_k_ * common_level_m;
    return rise_k * rise_k *
           (common * common * (1.0 + tc_rel_std_ * tc_rel_std_) + unread_offset_var_ * sensitivity_m2_per_v2 +
            unread_gain_var_ * level_sensitivity_m2);
  }
  /// Variance the adapted gain and offset leave in sensor i's corrected reading
  /// where its table reads `table_v` [V^2]; 0 when adaptation is off.
  double reading_variance(int i, double table_v) const {
    if (!enabled_) return 0.0;
    const double u = table_v - mid_v_;
    return std::max(0.0, u * u * pgg(i) + 2.0 * u * pgd(i) + pdd(i));
  }
  /// What reading_variance() holds beyond the start-up prior (which stands for the
  /// small drift any calibration has had since, already in the published sigma's
  /// systematic term): the widening a known temperature change or a re-opening
  /// brought, not learnt yet [V^2].
  double drift_variance(int i, double table_v) const {
    if (!enabled_) return 0.0;
    const double u = table_v - mid_v_;
    return std::max(0.0, reading_variance(i, table_v) - (u * u * p0_gg_ + p0_dd_));
  }
  /// What the adapted gains and offsets leave in a combination sum_i c_i y_i of the
  /// corrected readings of the sensors in `mask` (sensor i's table reading
  /// `table_v[i]`): the sensors' joint uncertainty, their correlations included (what
  /// the array cannot tell from a position shift is correlated between them)
  /// [V^2 times c^2]. `beyond_prior` is set to what it holds beyond the start-up
  /// prior (the calibration's small drift, taken as independent between sensors).
  double combined_variance(const std::array<double, kMaxHalls>& c, const std::array<double, kMaxHalls>& table_v,
                           std::uint32_t mask, double& beyond_prior) const;
  /// Whether the sensors' gains and offsets are learnt jointly (the motor was found
  /// a kelvin or more from its calibration temperature) or sensor by sensor.
  bool joint() const { return joint_; }
  /// Sum of the squared temperature changes the sensors' covariance was widened for
  /// so far [K^2]: it grows with every widening.
  double widened_k2() const { return widened_k2_; }
  /// Sensor i's own gain change (on top of the common one), and its total change.
  double gain(int i) const { return gamma_[static_cast<std::size_t>(i)]; }
  double total_gain(int i) const { return (1.0 + common_gain_) * (1.0 + gain(i)) - 1.0; }
  /// The gain every sensor shares, relative to the calibration, and its variance
  /// (0 when adaptation is off: the fix then takes the calibration's gain as exact).
  double common_gain() const { return common_gain_; }
  double common_gain_variance() const { return enabled_ ? p_common_ : 0.0; }
  /// The zero-field output the gains act about [V].
  double mid_v() const { return mid_v_; }
  /// Adds to the table's own error in one sample's residual (hall_adaptation_model_std_v):
  /// what a table made without a ruler is further off by (HallArray::table_error_v2) [V^2].
  void add_model_variance(double v2) {
    if (v2 > 0.0) model_var_v2_ += v2;
  }
  double offset_v(int i) const { return delta_[static_cast<std::size_t>(i)]; }
  /// The sensor's gain or offset ran into its bound: more change than slow drift explains.
  bool beyond_limits(int i) const { return at_limit_[static_cast<std::size_t>(i)]; }
  /// Times a sensor's parameters were re-opened by the CUSUM (a fast change).
  std::uint64_t reopenings() const { return reopenings_; }

 private:
  void residuals(const RawSample& raw, const HallTable& table, double x_m, double common_mode_v, std::uint32_t mask,
                 std::uint32_t learn_only_mask, std::array<double, kMaxHalls>& r, std::array<double, kMaxHalls>& u,
                 std::array<double, kMaxHalls>& sl, std::uint32_t& usable, double& s_sr, double& s_ss) const;
  void learn(const std::array<double, kMaxHalls>& r, const std::array<double, kMaxHalls>& u,
             const std::array<double, kMaxHalls>& sl, std::uint32_t usable, double s_sr, double s_ss,
             std::uint32_t learn_only_mask, double share);
  struct Cusum {
    double up = 0.0, down = 0.0;
  };
  bool enabled_;
  int sensors_;
  double mid_v_;
  double lo_v_, hi_v_;
  double noise_var_v2_;
  double q_gain_, q_offset_;          ///< per-sample random-walk variances
  double q_common_, p0_common_;       ///< the common gain's random walk and start-up variance
  double model_var_common_;           ///< the least variance one fix's common gain can have
  double model_var_v2_;               ///< the least variance one sample's residual has [V^2]
  double common_tc_per_k_;            ///< remanence + mean Hall sensitivity coefficient [1/K]
  double tc_rel_std_;
  /// Per sensor, how far its own gain [1/K] and offset [V/K] may move per kelvin
  /// beyond what is followed: the data sheet's spread, or with a thermal
  /// calibration what its coefficients leave.
  std::array<double, kMaxHalls> gain_tc_std_{}, offset_tc_std_v_{};
  /// With a thermal calibration: each sensor's own coefficients, followed as the
  /// rise changes (follow_rise), and the rise followed so far [K].
  bool thermal_ = false;
  std::array<double, kMaxHalls> gain_tc_{}, offset_tc_v_{};
  double followed_k_ = 0.0;
  double moved_v2_ = 0.0;
  /// `var_k2`: how well the rise is known [K^2]; the sensors follow the rise as far as
  /// that allows against the prior spread of an unread rise, and their covariance
  /// widens by what the coefficients make of the rest.
  void follow_rise(double to_k, double var_k2 = 0.0);
  double unread_rise_var_k2_ = 100.0;  ///< the prior spread of a rise not read [K^2]
  double follow_var_k2_ = 0.0;         ///< the rise's variance the covariance holds so far [K^2]
  double infer_n_ = 0.0, infer_places_ = 0.0;  ///< the fixes' count and new places in the average
  /// A change of temperature not read moves a sensor by its coefficients (not
  /// followed there) and their spread: the largest of the sensors', squared.
  double unread_gain_var_ = 0.0, unread_offset_var_ = 0.0;
  static constexpr double kReadingStdK = 0.3;         ///< one reading of the node: noise and resolution [K]
  static constexpr double kTemperatureAverageS = 3.0; ///< the reading is averaged over about this long [s]
  double temperature_alpha_;
  double smoothed_k_ = 0.0;           ///< the averaged rise [K]
  double temperature_k_ = 0.0;        ///< the rise last applied [K]
  bool temperature_known_ = false;
  /// Each sensor's gain and offset may have moved by what a change of temperature
  /// from `from_k` to `to_k` (rises over the calibration) allows.
  void widen_for_rise(double from_k, double to_k);
  /// Without a thermal calibration: what the published sigma holds (look_gg_,
  /// look_dd_) widens by the data sheet's spreads times the part of the rise the
  /// fixes' thermometer has not read (a reading of variance var_k2 against the
  /// unread band), as far as it has not widened for it yet.
  void widen_for_unread_share(double var_k2);
  double unread_share_var_k2_ = 0.0;  ///< the unread rise's variance the looks hold so far [K^2]
  /// Without a thermal calibration: what a sensor's gain or offset has been learnt to
  /// be at each step of the rise says what its own temperature coefficient is (a
  /// regression of the parameter on the rise, a + c r), and each step moves it by c.
  struct Coefficient {
    Coefficient() = default;
    Coefficient(double p0, double s2) : paa(p0), pcc(s2), pu(p0) {}
    double a = 0.0, c = 0.0;              ///< at the calibration; per kelvin
    double paa = 0.0, pac = 0.0, pcc = 0.0;
    double u = 0.0, pu = 0.0;             ///< the unlearnt track: mean and variance
    /// At a step of the rise from r by d_k, the learnt value x known to p: updates
    /// (a, c) with what the fixes said since the last step and returns c (pcc is what
    /// is left of it); the track restarts from x moved by c d_k (variance capped at
    /// cap). Without `predict` the step is not followed: returns 0, and the track
    /// widens by the whole spread s2.
    double step(double x, double p, double r, double d_k, double cap, double s2, bool predict);
  };
  std::array<Coefficient, kMaxHalls> gain_coefficient_{}, offset_coefficient_{};
  /// The least share of a sensor's prior at a rise the learning must have explained
  /// before what it learnt is taken for the sensor's coefficient.
  static constexpr double kLearntCoefficientShare = 0.5;
  /// Steps of the rise closer together than this are not the motor's temperature [s].
  static constexpr double kLearntCoefficientStepS = 0.5;
  std::uint64_t clock_ = 0, last_step_clock_ = 0;  ///< readings of the rise taken [samples]
  double ts_s_ = 0.0;
  // The rise the fixes' common gain shows (observe_fix_gain): its weighted average
  // over about kInferAverageS, first taken in after kInferFirstS.
  static constexpr double kInferAverageS = 0.05;
  static constexpr double kInferFirstS = 0.02;  ///< the first reading: a shorter average
  /// A fix is a reading of the thermometer only if its variance of the common gain is
  /// at most this share of the start-up prior's (observe_fix_gain).
  static constexpr double kInferKnownShare = 0.5;
  double infer_decay_ = 0.0;
  double infer_wg_ = 0.0, infer_w_ = 0.0;
  double infer_wo_ = 0.0;  ///< the weighted sum of what the offsets' drift adds to each reading's variance
  std::uint64_t infer_samples_ = 0, infer_first_samples_ = 0;
  bool inferred_started_ = false;
  double inferred_k_ = 0.0;           ///< the rise last applied, as large as the coefficients allow [K]
  double common_gain_ = 0.0, p_common_ = 0.0;
  double p0_gg_, p0_dd_;              ///< start-up variances, where the random walk stops
  double gain_limit_, offset_limit_v_;
  double reopen_threshold_;
  double max_shift_m_;
  double rail_guard_v_;  ///< table values this close to a rail are not learnt from  ///< larger prediction errors teach nothing (not linear)
  double reopen_gain_var_, reopen_offset_var_;
  std::array<double, kMaxHalls> gamma_{}, delta_{};
  // Every sensor's gain and offset are learnt together: what one sample cannot tell
  // apart (a shift of the position against the sensors' common pattern of drift) is
  // held as a correlation, not forgotten. The joint covariance of (gamma_i, delta_i)
  // for all sensors, gamma_i at 2i and delta_i at 2i + 1. (joint_update adds the
  // position error of the sample being learnt from as one more state, a nuisance
  // re-opened for every sample; its row and column live only there.)
  static constexpr int kParams = 2 * kMaxHalls;
  double p_[kParams][kParams] = {};
  /// The common gain's covariance with each parameter (joint learning: joint_update
  /// considers the common gain, common_jointly learns it).
  double pgc_[kParams] = {};
  void common_jointly(double relative_change, double variance, double share);
  void flush_common();
  // common_jointly's updates of the sensors since the last flush_common (common_count_
  // fixes), applied together there.
  double common_loss_ = 0.0, common_move_ = 0.0, common_scale_ = 1.0;
  int common_count_ = 0;
  /// Sensor i's gain and offset moved by these, within their bounds (a move beyond
  /// them sets at_limit_).
  void move_sensor(int i, double d_gain, double d_offset_v);
  /// The same, moved by a change of temperature (a prediction): the largest change it
  /// makes to a reading is kept for take_moved_v2().
  void move_sensor_by_rise(int i, double d_gain, double d_offset_v);
  /// Sensor i's own 2 x 2 block of p_ kept a covariance: variances above zero, their
  /// covariance within what they allow, mirrored.
  void keep_block(int i);
  double& pgg(int i) { return p_[2 * i][2 * i]; }
  double& pgd(int i) { return p_[2 * i][2 * i + 1]; }
  double& pdd(int i) { return p_[2 * i + 1][2 * i + 1]; }
  double pgg(int i) const { return p_[2 * i][2 * i]; }
  double pgd(int i) const { return p_[2 * i][2 * i + 1]; }
  double pdd(int i) const { return p_[2 * i + 1][2 * i + 1]; }
  /// The joint update runs on every kJointEvery-th sample that learns (its cost
  /// grows with the square of the sensors); the samples between add their share.
  static constexpr int kJointEvery = 4;
  static constexpr double kJointLeastShare = 1e-3;  ///< the least share a joint update takes
  // The least drift the published sigma may hold (combined_variance): the joint update
  // counts a new place every kNewPlaceShareOfPitch, which is right for the readings'
  // noise, but the table's own error (model_var_v2_) repeats until the carriage has
  // moved a good part of a period on. Each sensor's gain and offset variance as
  // independent looks of that error would leave them, one per kModelShareOfPitch of
  // travel (no correlations; the random walk, widening and re-opening as in p_): the
  // published drift is never below what these allow.
  static constexpr double kModelShareOfPitch = 0.25;
  std::array<double, kMaxHalls> look_gg_{}, look_dd_{};
  static constexpr double kJointFromK = 1.0;        ///< joint learning from this far off calibration [K]
  bool joint_ = false;
  double widened_k2_ = 0.0;  ///< sum of the squared rises widened for [K^2]
  double farthest_k2_ = 0.0; ///< the square of the farthest rise widened for [K^2]
  int joint_count_ = 0;
  double joint_share_ = 0.0;
  void joint_update(const std::array<double, kMaxHalls>& r, const std::array<double, kMaxHalls>& u,
                    const std::array<double, kMaxHalls>& sl, std::uint32_t learn_mask, std::uint32_t learn_only_mask,
                    double share);
  std::array<Cusum, kMaxHalls> cusum_{};
  std::array<bool, kMaxHalls> at_limit_{};
  std::uint64_t reopenings_ = 0;
};

}  // namespace ve::core
