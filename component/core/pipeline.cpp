#include "pipeline.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

#include "status.hpp"

namespace ve::core {

namespace {
// A disagreement among the Hall sensors is averaged over this long for the
// published sigma, and held (decaying) this long for the blame test.
constexpr double kDisagreementAverageS = 0.25;
constexpr double kDisagreementHoldS = 1.0;
// The Hall adaptation starts learning this long after the filter (re)started, or
// after kAdaptSettleMovingS while the carriage moves fast enough that a sample
// carries at least kAdaptSettleMovingShare of a new place's information (the
// filter has followed the fixes for several of its time constants by then).
// Waiting the whole settling time cost a motor started warm at 1 m/s its first
// magnet periods unlearnt: on the population benchmark's +10 K ramp at 1 m/s, the
// worst motor's RMS went from 2.0 to 0.96 um and VALID from 94.9 to 99.4 % of the
// window (motors 21-40, tuned on by nobody: 1.45 to 0.87 um, VALID 73.5 to 92.1 %).
// Starting from rest it must wait: learning in the first slow centimetres, where a
// sensor's gain, its offset and the position hardly separate, left 5 m/s^2 runs
// worse (a one-off comparison) ...
constexpr double kAdaptSettleS = 0.05;
constexpr double kAdaptSettleMovingS = 0.01;
constexpr double kAdaptSettleMovingShare = 0.5;
// ... and learns only from fixes within this many sigmas of the prediction.
constexpr double kAdaptInnovationSigma = 4.0;
// A sensor is blamed for a disagreement only if removing it leaves a fix within
// this many sigmas of the prediction, and removing any other does not.
constexpr double kBlameAgreementSigma = 4.0;
// A start position that finds no fix this many samples in a row is given up:
// search as at a start without a known position.
constexpr int kLostAfterFailedAcquisitions = 20;
}  // namespace

AxisPipeline::AxisPipeline(const PipelineConfig& config, HallTable table)
    : cfg_(config),
      hall_(config.motor, std::move(table)),
      kf_(config.motor.sample_period_s(), config.motor.filter, config.sensors),
      homing_(config.motor.magnet_pitch_m, config.signature),
      period_ns_(static_cast<std::int64_t>(std::llround(1e9 / config.motor.sample_rate_hz))),
      adapt_(config.motor, config.motor.sample_period_s(), &config.sensors) {
  // What a table made without a ruler leaves in a fix from place to place (its
  // calibration measured it in the fast motion): at speed it changes faster than the
  // filter averages, like noise. Left out, the fixes of motor 67 of the population
  // (magnets placed to 46 um, 4 um beyond the fixes' noise) were trusted to 0.6 um:
  // point-to-point velocity 0.40 mm/s RMS, and 10 K cold the filter took those fixes
  // for steps of acceleration until it lost the track.
  hall_.add_fix_noise(config.sensors.hall_fix_excess_std_m);
  // ... and what it leaves in each sensor's reading, which judging the sensors allows
  // for: without it, motor 67's healthy sensors were the odd one out where its table's
  // curves are 2-4 mV apart (at 0.112-0.116 m), and up to five of its eight were
  // flagged in turn.
  hall_.add_table_error(config.sensors.hall_fix_excess_std_m);
  // The adaptation learns against the same table: where a sensor comes out of
  // saturation motor 67's reads 5-9 mV off it, which was learnt as a gain of -1.35 %.
  adapt_.add_model_variance(hall_.table_error_v2());
  const double an = config.motor.accelerometer.noise_mps2;
  accel_var_ = an * an;
  const int n = std::min(config.motor.hall.count, kMaxHalls);
  all_halls_mask_ = (1u << n) - 1u;
  min_healthy_ = config.motor.filter.min_healthy_halls > 0 ? config.motor.filter.min_healthy_halls : std::max(1, n - 1);
  readmit_samples_ = std::max(1, static_cast<int>(std::lround(config.motor.filter.sensor_readmit_s * config.motor.sample_rate_hz)));
  blame_wait_samples_ = readmit_samples_;
  disagreement_decay_ = std::exp(-1.0 / (kDisagreementAverageS * config.motor.sample_rate_hz));
  hold_decay_ = std::exp(-1.0 / (kDisagreementHoldS * config.motor.sample_rate_hz));
  settle_samples_ = std::max(1, static_cast<int>(std::lround(kAdaptSettleS * config.motor.sample_rate_hz)));
  settle_moving_samples_ = std::max(1, static_cast<int>(std::lround(kAdaptSettleMovingS * config.motor.sample_rate_hz)));
  table_noise_v2_ = config.sensors.table_noise_v * config.sensors.table_noise_v;
  {
    // A sensor's slope, root mean square over a magnet period: 2 pi A / (pitch sqrt 2).
    const double slope = 2.0 * M_PI * config.motor.hall.amplitude_v / (config.motor.magnet_pitch_m * std::sqrt(2.0));
    quantisation_travel_m_ = config.motor.adc.lsb_v() / std::max(slope, 1e-9);
  }
}

HallFix AxisPipeline::solve_robust(const RawSample& sample, double guess_m, double common_mode_v,
                                   std::uint32_t use_mask, std::uint32_t& outlier_mask, bool& ambiguous) {
  outlier_mask = 0;
  ambiguous = false;
  const double limit = cfg_.motor.filter.sensor_chi2_limit;
  HallFix fix = hall_.solve(sample, guess_m, common_mode_v, use_mask, &adapt_);
  // Whether the table's own error explains the disagreement (always so when there is
  // none): the odd sensor is still left out of the fix, but not blamed for it.
  table_explains_ = fix.ok && fix.chi2_table <= limit;
  if (fix.ok && fix.chi2 <= limit) return fix;
  // The sensors disagree (or one reads a rail where the others place it in the
  // middle): find the one sensor whose removal leaves a consistent fix, and among
  // such fixes take the one closest to the prediction. When several removals
  // would do (always so with two sensors out of saturation), the fix still takes
  // the closest, but the sensor is blamed only if the prediction singles it out.
  const double var_pred = kf_.covariance()(FusionFilter::kPos, FusionFilter::kPos);
  double best_score = std::numeric_limits<double>::infinity();
  HallFix best;
  int candidates = 0, agreeing = 0;
  double lo_m = std::numeric_limits<double>::infinity(), hi_m = -lo_m;
  for (int i = 0; i < kMaxHalls; ++i) {
    const std::uint32_t bit = 1u << i;
    if (!(use_mask & sample.hall_valid_mask & bit)) continue;
    const HallFix f = hall_.solve(sample, guess_m, common_mode_v, use_mask & ~bit, &adapt_);
    if (!f.ok || f.chi2 > limit) continue;
    ++candidates;
    lo_m = std::min(lo_m, f.position_m);
    hi_m = std::max(hi_m, f.position_m);
    const double d = f.position_m - guess_m;
    const double score = d * d / (var_pred + disagreement_hold_m2_ + f.variance_m2);
    if (score <= kBlameAgreementSigma * kBlameAgreementSigma) ++agreeing;
    if (score < best_score) {
      best_score = score;
      best = f;
      outlier_mask = bit;
    }
  }
  // Unambiguous: one removal makes the rest consistent, or several do but only
  // one of them agrees with the prediction (a drift of every sensor leaves them
  // all far from it).
  ambiguous = candidates > 1 && !(agreeing == 1 && best_score <= kBlameAgreementSigma * kBlameAgreementSigma);
  if (ambiguous) {
    // Which sensor is off cannot be told: the fix is only as good as the spread of
    // the places the sensors point to. That error repeats from sample to sample
    // (a drift, not noise), so it is held apart from the filter, which would
    // average it away, and added to the published sigma (see step()).
    const double half_spread = 0.5 * (hi_m - lo_m);
    disagreement_seen_m2_ = std::max(disagreement_seen_m2_, half_spread * half_spread);
  }
  if (outlier_mask) return best;
  // No single sensor explains the disagreement (all of them drifted, or the
  // model is off): its size, chi-square over the noise, is held apart likewise.
  if (fix.ok && fix.sensors_used > 1)
    disagreement_seen_m2_ = std::max(disagreement_seen_m2_,
                                     fix.variance_m2 * std::max(0.0, fix.chi2 / (fix.sensors_used - 1) - 1.0));
  return fix;
}

void AxisPipeline::update_hall_health(std::uint32_t used_mask, std::uint32_t outlier_mask) {
  // A sensor judged faulty stays out until it has agreed with the estimate over
  // enough motion (readmission_step): judging it healthy again against single
  // fixes made by fewer sensors could let two failed sensors agree on a wrong
  // place (seen in the tests), and a drive must never get that.
  const auto& f = cfg_.motor.filter;
  const double alpha = 1.0 / std::max(1.0, f.sensor_fault_time_constant_samples);
  for (int i = 0; i < kMaxHalls; ++i) {
    const std::uint32_t bit = 1u << i;
    if (!(used_mask & bit)) continue;
    double& score = fault_score_[i];
    score += alpha * (((outlier_mask & bit) ? 1.0 : 0.0) - score);
    // A gain or offset beyond anything slow drift explains is a fault as well.
    if (score > f.sensor_fault_on || adapt_.beyond_limits(i)) {
      faulty_mask_ |= bit;
      readmit_streak_[i] = 0;
    }
  }
}

void AxisPipeline::readmission_step(const RawSample& raw, double x_m, double common_mode_v) {
  const auto& f = cfg_.motor.filter;
  const double lo = cfg_.motor.adc.min_v + cfg_.motor.hall.saturation_margin_v;
  const double hi = cfg_.motor.adc.max_v - cfg_.motor.hall.saturation_margin_v;
  for (int i = 0; i < kMaxHalls; ++i) {
    const std::uint32_t bit = 1u << i;
    if (!(faulty_mask_ & bit)) continue;
    const double y = raw.hall_v[static_cast<std::size_t>(i)];
    if (!(raw.hall_valid_mask & bit) || !(y > lo && y < hi)) continue;  // a rail reading says nothing
    double std_v = 0.0;
    const double r = adapt_.residual(raw, hall_.table(), i, x_m, common_mode_v, std_v);
    std_v = std::sqrt(std_v * std_v + hall_.table_error_v2());
    if (std::abs(r) > f.sensor_readmit_sigma * std_v || adapt_.beyond_limits(i)) {
      readmit_streak_[i] = 0;
      continue;
    }
    if (readmit_streak_[i]++ == 0) readmit_lo_m_[i] = readmit_hi_m_[i] = x_m;
    readmit_lo_m_[i] = std::min(readmit_lo_m_[i], x_m);
    readmit_hi_m_[i] = std::max(readmit_hi_m_[i], x_m);
    if (readmit_streak_[i] >= readmit_samples_ &&
        readmit_hi_m_[i] - readmit_lo_m_[i] >= 0.5 * cfg_.motor.magnet_pitch_m) {
      faulty_mask_ &= ~bit;
      fault_score_[i] = 0.0;
      readmit_streak_[i] = 0;
      ++readmitted_;
    }
  }
}

bool AxisPipeline::acquire(const RawSample& sample) {
  const double p = cfg_.motor.magnet_pitch_m;
  double lo, hi;
  bool homed;
  const HallTable& table = hall_.table();
  const double x_now = kf_.state()(FusionFilter::kPos);
  // Lost: the filter's position is off the table (or not a number), or a start
  // position given from outside (the machine file, a kept position) finds no fix
  // for kLostAfterFailedAcquisitions samples. Start again as if nothing were known:
  // the period is not known then (signature homing, when on, finds it again). Near
  // a position that was good, a failed search is only tried again: a noisy sensor
  // can make it fail for a while, and a relative position would be worse.
  const bool lost =
      started_ ? (!std::isfinite(x_now) || x_now < table.start_m - p || x_now > table.end_m() + p)
               : acquire_failures_ >= kLostAfterFailedAcquisitions;
  if (started_ && !lost) {
    // Re-acquisition: search half a pitch either side of where the filter says the
    // carriage is. The period is still known only if that is certain to well
    // within a pitch.
    const double x = x_now;
    lo = x - 0.5 * p;
    hi = x + 0.5 * p;
    homed = homed_ && std::sqrt(kf_.covariance()(FusionFilter::kPos, FusionFilter::kPos)) < p / 8.0;
  } else if (cfg_.start_position_known && !lost) {
    lo = cfg_.start_position_m - 0.5 * p;
    hi = cfg_.start_position_m + 0.5 * p;
    homed = true;
  } else {
    // Relative: any period will do (on an ideal track they all look alike). Take
    // one in the middle of the table, so that the relative position has room both ways.
    const HallTable& t = table;
    lo = t.start_m + std::floor(0.5 * (t.end_m() - t.start_m) / p) * p;
    hi = lo + p;
    homed = false;
  }
  adapt_.correct(sample, 0.0, corrected_);
  const HallFix fix = hall_.acquire(corrected_, lo, hi, 0.0, all_halls_mask_ & ~faulty_mask_, &adapt_);
  if (!fix.ok) return false;
  kf_.reset(fix.position_m, fix.variance_m2, accel_reading(sample), accel_usable(sample));
  homed_ = homed;
  // Signature homing: search (not homed) or check the start position (homed from a
  // configured or kept position) on the first motion.
  if (cfg_.signature_homing && (!homed_ || !started_)) homing_.start(hall_, fix.position_m);
  started_ = true;
  settled_samples_ = 0;
  rejected_in_row_ = 0;
  without_fix_in_row_ = 0;
  lost_in_row_ = 0;
  return true;
}

void AxisPipeline::signature_step(const RawSample& sample, double x_hall_m, double common_mode_v, std::uint32_t use) {
  if (!homed_ && homing_.state() != SignatureHoming::State::collecting) homing_.start(hall_, x_hall_m);
  if (!homing_.feed(hall_, sample, x_hall_m, common_mode_v, use)) return;
  const double offset = homing_.offset_m();
  if (homed_) {
    // Checking a start position: within the period it named, nothing to do.
    if (std::abs(offset) < 0.5 * cfg_.motor.magnet_pitch_m) return;
    ++homing_corrections_;
  }
  // Into the absolute frame. The relative run used another period's table, whose
  // tolerances differ by tens of micrometres: let the filter settle on the right one.
  kf_.shift_position(offset);
  kf_.inflate(4e-12, 4e-6, 0.0);
  homed_ = true;
}

bool AxisPipeline::use_frame(const RawSample& sample) const {
  return cfg_.motor.filter.use_frame_accelerometer && sample.accel_base_valid;
}

bool AxisPipeline::accel_usable(const RawSample& sample) const {
  const double range = cfg_.motor.accelerometer.range_mps2;
  if (!sample.accel_valid || std::abs(sample.accel_mps2) >= range) return false;
  return !use_frame(sample) || std::abs(sample.accel_base_mps2) < range;
}

double AxisPipeline::accel_reading(const RawSample& sample) const {
  // The moving accelerometer is inertial: it also feels the frame's motion, which
  // the Halls (on the frame's magnet track) do not. The frame accelerometer removes it.
  return use_frame(sample) ? sample.accel_mps2 - sample.accel_base_mps2 : sample.accel_mps2;
}

void AxisPipeline::update_accelerometer(const RawSample& sample) {
  bool used = false;
  const bool frame = use_frame(sample);
  const double r = frame ? 2.0 * accel_var_ : accel_var_;
  // Spike rejection by size: a sigma gate would also reject real acceleration steps.
  const double spike_sigma =
      cfg_.motor.filter.accel_spike_mps2 / std::sqrt(r + kf_.covariance()(FusionFilter::kAcc, FusionFilter::kAcc));
  kf_.update_accel(accel_reading(sample), r, spike_sigma, used);
}

const EncoderEstimate& AxisPipeline::step(const RawSample& sample) {
  std::uint32_t status = cfg_.calibrated ? status::kCalibrated : 0u;
  out_.t_ns = sample.t_ns;
  out_.seq = sample.seq;
  out_.samples_skipped = 0;
  // The sensor node's temperature, against the calibration's: the Hall adaptation
  // starts from (and follows) what the data sheet predicts for the difference.
  if (sample.temperature_valid && std::isfinite(cfg_.sensors.temperature_c))
    adapt_.temperature(sample.temperature_c - cfg_.sensors.temperature_c);
  // VALID asks for the temperature checked before this sample's fix was made: a first
  // reading of the fixes' thermometer (observe_fix_gain, below) widens the sensors'
  // covariance after this fix, whose sigma does not hold that widening yet.
  const bool temperature_checked = adapt_.temperature_checked();
  const double widened_k2 = adapt_.widened_k2();

  // Accelerometer health: missing, saturated, or dead (the same reading again and again).
  bool accel_ok = accel_usable(sample);
  if (sample.accel_valid) {
    accel_repeats_ = sample.accel_mps2 == last_accel_ ? accel_repeats_ + 1 : 0;
    last_accel_ = sample.accel_mps2;
    if (accel_repeats_ >= cfg_.motor.filter.accel_stuck_samples) accel_stuck_ = true;
    if (accel_repeats_ == 0) accel_stuck_ = false;
  }
  accel_ok = accel_ok && !accel_stuck_;
  out_.accel_stuck = accel_stuck_;
  kf_.set_accelerometer_available(accel_ok);
  if (!accel_ok) status |= status::kAccelFault;

  // Timing: predict once per nominal period elapsed, so dropped samples are
  // bridged by prediction; a long silence restarts the filter without the period.
  int steps = 1;
  if (initialised_) {
    const std::int64_t dt = sample.t_ns - last_t_ns_;
    const std::int64_t n = (dt + period_ns_ / 2) / period_ns_;
    if (n <= 0) {
      // A sample from the past (or twice the same): nothing new to learn.
      out_.status = (out_.status & ~status::kHallRejected) | status::kHallRejected;
      return out_;
    }
    if (static_cast<double>(dt) * 1e-9 > cfg_.max_gap_s) {
      initialised_ = false;
      homed_ = false;
    } else {
      steps = static_cast<int>(n);
      out_.samples_skipped = static_cast<std::uint32_t>(n - 1);
    }
  }
  last_t_ns_ = sample.t_ns;

  bool applied = false;
  bool accel_taken = false;
  out_.hall_sensors_used = 0;
  if (!initialised_) {
    initialised_ = acquire(sample);
    acquire_failures_ = initialised_ ? 0 : acquire_failures_ + 1;
    if (!initialised_) {
      out_.status = status | status::kHallRejected;
      return out_;
    }
    applied = true;
  } else {
    for (int i = 0; i < steps; ++i) kf_.predict();
    ++settled_samples_;
    // The accelerometer first: a step of acceleration it shows moves the prediction
    // the Hall fix is then judged against (the other way round, the fix of the
    // sample that shows a step would be rejected, and the output not VALID for it).
    if (accel_ok) {
      update_accelerometer(sample);
      accel_taken = true;
    }

    // The Halls saw the track at t - hall_delay; start the search there. The coil
    // field adds the same offset to every sensor, in proportion to the force.
    const auto& xp = kf_.state();
    const double guess = xp(FusionFilter::kPos) - cfg_.sensors.hall_delay_s * xp(FusionFilter::kVel);
    const double common_mode = cfg_.sensors.coil_field_v_per_mps2 * xp(FusionFilter::kAcc);
    std::uint32_t outlier = 0;
    bool ambiguous = false;
    const std::uint32_t use = all_halls_mask_ & ~faulty_mask_;
    // The readings as the calibration would have seen them (gains and offsets drift).
    adapt_.correct(sample, common_mode, corrected_);
    const HallFix fix = solve_robust(corrected_, guess, common_mode, use, outlier, ambiguous);
    out_.hall_sensors_used = fix.sensors_used;
    out_.hall_outlier_mask = outlier;
    // While the signature search runs, the filter follows another period's table
    // than the one the carriage is in: its sensors disagree by the two periods'
    // tolerances, which says nothing about their health (nor about their drift).
    const bool judge = fix.ok && !homing_in_progress();
    // Blame waits until the adaptation has had a moment after a start: a motor
    // warmer or colder than at calibration makes its most drifted sensor look like
    // the odd one out at first. (The fix itself leaves an outlier out all along.)
    if (judge && !ambiguous && settled_samples_ >= blame_wait_samples_)
      update_hall_health(use & sample.hall_valid_mask, table_explains_ ? 0u : outlier);
    // Learn gains and offsets against the prediction (made before this fix, so the
    // fix's own noise is not fed back) once the filter has settled after a start
    // (its start-up transient is not drift), and only from fixes the prediction
    // agrees with, the sensors' unexplained disagreement allowed for (a drift is
    // what makes them disagree): when the filter has to follow the Halls against
    // its model (an acceleration step, or anything the accelerometer does not
    // confirm), what it follows must not be learnt as drift.
    // How fast the fixes move to new places: what renews their repeating errors. A
    // sample taken where the last one was repeats its errors: it carries new
    // information in proportion to the travel since (a 200th of a magnet period
    // counts as a new place).
    const double speed = std::abs(xp(FusionFilter::kVel));
    const double share =
        std::min(1.0, speed * kf_.period_s() / (HallAdaptation::kNewPlaceShareOfPitch * cfg_.motor.magnet_pitch_m));
    const bool settled =
        settled_samples_ >= settle_samples_ || (settled_samples_ >= settle_moving_samples_ && share >= kAdaptSettleMovingShare);
    if (!adapt_.temperature_checked()) {
      // No fix has read the temperature yet: sigma holds what the sensors' own gains and
      // offsets may have moved this fix by since the calibration, as far as the data
      // sheet's spreads and hall_unread_temperature_rise_k allow (and the velocity's
      // sigma what that makes of the velocity at speed, below). Where the carriage stands
      // and no fix can read it (one sensor out of saturation), VALID follows that sigma;
      // elsewhere VALID waits for the reading, a few tens of ms. (Held at standstill only,
      // a motor started 10 K cold at 5 m/s^2 was 15 um and 1.5 mm/s off under a sigma of
      // 0.6 um and 0.08 mm/s until the reading: motor 60 of the population.)
      if (judge) {
        unread_place_ = fix.common_gain_variance > 0.0 && !adapt_.reads_temperature(fix.common_gain_variance) &&
                        share < kAdaptSettleMovingShare;
        unread_var_m2_ = adapt_.unread_rise_variance(cfg_.motor.filter.hall_unread_temperature_rise_k,
                                                     fix.common_level_m, fix.sensitivity_m2_per_v2,
                                                     fix.level_sensitivity_m2);
      }
    } else {
      unread_var_m2_ = 0.0;
      unread_place_ = false;
    }
    bool learn = judge && settled && rejected_in_row_ == 0;
    if (learn) {
      const double d = fix.position_m - guess;
      const double var = kf_.covariance()(FusionFilter::kPos, FusionFilter::kPos) + fix.variance_m2 +
                         disagreement_hold_m2_;
      learn = d * d <= kAdaptInnovationSigma * kAdaptInnovationSigma * var;
    }
    if (fix.ok && cfg_.signature_homing) signature_step(corrected_, guess, common_mode, use);
    // Without a temperature from the node, the common gain every fix sees is the
    // thermometer: how far the sensors may have drifted follows from it.
    // A move of the sensors by their thermal coefficients (on a reported temperature,
    // before this fix; on the fixes' thermometer, below, after it) shifts the fixes
    // from the next one on: a step of the model, which the filter's position takes
    // in at once instead of through its velocity.
    moved_v2_ = std::max(moved_v2_, adapt_.take_moved_v2());
    if (judge && fix.common_gain_variance > 0.0) adapt_.observe_fix_gain(fix.common_gain, fix.common_gain_variance, share,
                                                                        fix.common_gain_offset_var_per_k2);
    if (fix.ok && widen_filter_) {
      // The fixes the filter has taken so far carried the drift the sensors' covariance
      // now allows for, as errors that repeat along the travel, which its own variance
      // does not hold: its position widened by what the drift makes of a fix. (Its
      // velocity too, at the pattern's rate, made the velocity follow the fixes' noise:
      // twice the velocity error at 1 m/s on the motor population.)
      kf_.inflate(fix.drift_m2, 0.0, 0.0);
      widen_filter_ = false;
    }
    if (adapt_.widened_k2() > widened_k2) widen_filter_ = true;  // from the next fix on
    if (fix.ok && moved_v2_ > 0.0) {
      kf_.inflate(fix.sensitivity_m2_per_v2 * moved_v2_, 0.0, 0.0);
      moved_v2_ = 0.0;
    }
    if (fix.ok) {
      without_fix_in_row_ = 0;
      lost_in_row_ = 0;
      out_.hall_position_m = fix.position_m;
      out_.hall_std_m = std::sqrt(fix.variance_m2);
      if (fix.out_of_table) status |= status::kOutOfTravel;
      const double gate = cfg_.motor.filter.gate_sigma;
      // The gate allows for the sensors' recent unexplained disagreement (a drift
      // moves the fixes by more than their noise): such fixes are taken, not
      // rejected until the filter has to jump to them.
      const double fix_var = fix.variance_m2;
      const double wide_gate = gate * std::sqrt(1.0 + disagreement_var_m2_ / fix.variance_m2);
      // A drift the adaptation has not learnt yet moves the fixes by a pattern that
      // repeats with the magnet period, which the frame vibration's resonator takes
      // up when the two frequencies are near (then rings with it once the drift is
      // learnt): once it is, the resonator is checked against the calibration's.
      {
        const bool unlearnt = fix.drift_m2 > fix.variance_m2;
        if (drift_unlearnt_ && !unlearnt) kf_.doubt_vibration();
        drift_unlearnt_ = unlearnt;
      }
      out_.hall_innovation_sigma = kf_.update_hall(fix.position_m, fix_var, wide_gate, applied);
      if (learn) {
        // The gain every sensor shares, as this fix saw it; then each sensor's own,
        // each sample worth its share of a new one.
        adapt_.update_common(fix.common_gain, fix.common_gain_variance, share);
        // An outlier nobody can be blamed for (a drift) is exactly what must learn.
        adapt_.update(sample, hall_.table(), guess, common_mode, use & ~(ambiguous ? 0u : outlier), faulty_mask_,
                      share);
        // ... and see whether a faulty sensor agrees again.
        if (faulty_mask_) readmission_step(sample, guess, common_mode);
      }
      // The quantisation error repeats while the readings stay on their ADC steps;
      // the filter averages it over as many steps as the carriage crosses within
      // the fixes it averages (the ratio of a fix's variance to its own).
      const double p_pos = kf_.covariance()(FusionFilter::kPos, FusionFilter::kPos);
      const double averaged_s = kf_.period_s() * std::max(1.0, fix_var / std::max(p_pos, 1e-30));
      const double steps = speed * averaged_s / quantisation_travel_m_;
      quantisation_var_m2_ = fix.quantisation_m2 / (1.0 + steps);
      // Likewise the table's own noise, independent from node to node: averaged over
      // the nodes the carriage crosses.
      const double nodes = speed * averaged_s / hall_.table().step_m;
      table_var_m2_ = table_noise_v2_ * fix.sensitivity_m2_per_v2 / (1.0 + nodes);
      // The coil field is known to the calibration's sigma: its error is an offset on
      // every reading in proportion to the force, and moves the fix by the fix's
      // sensitivity to a common offset. Taken as it is now (the acceleration changes
      // as fast as the filter averages), and its change with the jerk as a velocity error.
      const double coil_std = cfg_.sensors.coil_field_std_v_per_mps2 * fix.offset_sensitivity_m_per_v;
      const double coil_m = coil_std * kf_.state()(FusionFilter::kAcc);
      const double coil_mps = coil_std * kf_.state()(FusionFilter::kJerk);
      coil_var_m2_ = coil_m * coil_m;
      coil_jerk_var_ = coil_mps * coil_mps;
      // A gain or offset error moves the fixes by a pattern that repeats with the
      // magnet period: it averages out over a good part of one.
      const double quarters = speed * averaged_s / (0.25 * cfg_.motor.magnet_pitch_m);
      const double fresh_drift_m2 = fix.drift_m2 / (1.0 + quarters);
      // What the fixes before this one made of the position stays in it until the
      // filter has averaged it out: each fix moves the estimate by about p_pos /
      // fix_var of the way to itself. A fix whose drift is small (one sensor out of
      // saturation, read near its mid level; or the first fixes at speed after a
      // start from rest) says nothing about the error the earlier ones left, and sigma
      // had dropped with it at once: motor 52 of the population (3 Halls), 10 K cold
      // from rest, sigma 4.2 -> 1.1 um in one sample while the position was 7-8 um off
      // (VALID at 8.1 um).
      const double keep = std::max(0.0, 1.0 - p_pos / std::max(fix_var, p_pos));
      drift_var_m2_ = std::max(fresh_drift_m2, drift_var_m2_ * keep * keep);
      // ... and, in motion, that pattern is a velocity error too: a position error
      // repeating with the magnet period, crossed at this speed, changes at 2 pi v / pitch.
      const double pattern_rate = 2.0 * M_PI * speed / cfg_.motor.magnet_pitch_m;
      drift_velocity_var_ = fresh_drift_m2 * pattern_rate * pattern_rate;
      pattern_rate_ = pattern_rate;
      averaged_s_ = averaged_s;
      if (applied) {
        rejected_in_row_ = 0;
      } else if (++rejected_in_row_ >= cfg_.motor.filter.hall_rejections_before_reset) {
        // Several fixes in a row disagree with the prediction: a spike would not
        // persist, so the motion changed faster than the model allows (a step in
        // acceleration). Widen the kinematic covariance by what such a step
        // explains and follow the Halls. The fix came from a local search around
        // the prediction, so it is in the same magnet period.
        const double nu = fix.position_m - xp(FusionFilter::kPos);
        const double span_s = rejected_in_row_ * kf_.period_s();
        // Without the accelerometer nothing would hold a widened acceleration: then
        // only position and velocity are widened.
        const double acc_var = accel_ok ? 4.0 * nu * nu / (span_s * span_s * span_s * span_s) : 0.0;
        kf_.inflate(nu * nu, 4.0 * nu * nu / (span_s * span_s), acc_var);
        out_.hall_innovation_sigma = kf_.update_hall(fix.position_m, fix_var, 0.0, applied);
        rejected_in_row_ = 0;
      }
    } else {
      ++without_fix_in_row_;
      // Every sensor in use reads a rail, and the table has each of them there at the
      // prediction (or no sensor has a reading in this sample): the carriage stands or
      // passes where no fix can be made, which says nothing against the prediction.
      // The filter bridges such a stretch on the accelerometer, its sigma growing
      // (VALID goes after max_samples_without_fix all the same). A search would find
      // no more than the prediction, and where the sensors left see one phase of the
      // pattern only (three Halls, one of them flagged, the other two half a period
      // apart) it can take the mirror image of the place within the period: motor 54
      // of the population benchmark, which had lost its middle sensor to a stretch of
      // table, was taken 0.75 mm off so. Bridged only while the position is known to
      // a sixteenth of a pitch.
      const double bridge_m = cfg_.motor.magnet_pitch_m / 16.0;
      const bool unreadable = fix.sensors_used == 0 && fix.conflict_mask == 0 && accel_ok &&
                              kf_.covariance()(FusionFilter::kPos, FusionFilter::kPos) < bridge_m * bridge_m;
      if (!unreadable) ++lost_in_row_;
      if (lost_in_row_ >= cfg_.max_samples_without_fix) initialised_ = false;  // re-acquire near the prediction
    }
  }
  if (!applied) status |= status::kHallRejected;

  // Just (re)acquired: the accelerometer after the Halls that placed the filter.
  if (accel_ok && !accel_taken) update_accelerometer(sample);

  const auto& x = kf_.state();
  const auto& p = kf_.covariance();
  out_.position_m = x(FusionFilter::kPos);
  out_.velocity_mps = x(FusionFilter::kVel);
  out_.acceleration_mps2 = x(FusionFilter::kAcc);
  out_.accel_bias_mps2 = x(FusionFilter::kBias);
  out_.accel_scale = x(FusionFilter::kScale);
  // Disagreement among the sensors that no sensor can be blamed for: its average
  // over about the last quarter second (a lasting drift, not one odd sample), on
  // top of the filter's own variance.
  disagreement_var_m2_ += (1.0 - disagreement_decay_) * (disagreement_seen_m2_ - disagreement_var_m2_);
  // The blame test remembers the largest recent one (decaying over about a
  // second): a sensor is not blamed while the array has just disagreed without one.
  disagreement_hold_m2_ = std::max(disagreement_seen_m2_, disagreement_hold_m2_ * hold_decay_);
  disagreement_seen_m2_ = 0.0;
  // Without a ruler the table's scale is the magnet track's own, known to
  // track_scale_std: an error in proportion to the distance from home (position 0).
  const double scale_m = cfg_.sensors.track_scale_std * out_.position_m;
  // Without a ruler, beyond the calibration's slow passes (where it turned) the table
  // rests on the accelerometer's bridges, known to table_outside_std_m only.
  const bool beyond_passes = cfg_.sensors.trusted_span_known() && (out_.position_m < cfg_.sensors.table_trusted_from_m ||
                                                                    out_.position_m > cfg_.sensors.table_trusted_to_m);
  const double beyond_m = beyond_passes ? cfg_.sensors.table_outside_std_m : 0.0;
  out_.position_std_m =
      std::sqrt(kf_.position_variance() + disagreement_var_m2_ + quantisation_var_m2_ + table_var_m2_ + drift_var_m2_ +
                unread_var_m2_ + coil_var_m2_ + scale_m * scale_m + beyond_m * beyond_m);
  const double scale_mps = cfg_.sensors.track_scale_std * out_.velocity_mps;
  // Position errors that repeat with the magnet period: crossed at this speed they are
  // velocity errors at the pattern rate, which the filter passes as far as it follows
  // its fixes (first order, over the time it averages them).
  const double wt = pattern_rate_ * averaged_s_;
  const auto at_pattern_rate = [&](double position_var_m2) {
    return position_var_m2 * pattern_rate_ * pattern_rate_ / (1.0 + wt * wt);
  };
  // The disagreement (in the published sigma above). Without it a motor 10 K off its
  // calibration temperature had a velocity sigma of 0.03 mm/s against 0.1-0.3 mm/s of
  // error while the sensors' learning settled after a start (motor 8 of the population
  // at 1 m/s: 35 % of the velocity within 2 sigma).
  const double disagreement_velocity_var = at_pattern_rate(disagreement_var_m2_);
  // The coil field's error likewise: the fix's sensitivity to it changes along the
  // magnet period, and with the acceleration.
  const double coil_velocity_var = at_pattern_rate(coil_var_m2_) + coil_jerk_var_;
  // The drift a temperature not read yet may have put in the fixes.
  const double unread_velocity_var = at_pattern_rate(unread_var_m2_);
  out_.velocity_std_mps = std::sqrt(kf_.velocity_variance() + drift_velocity_var_ + disagreement_velocity_var +
                                    coil_velocity_var + unread_velocity_var + scale_mps * scale_mps);
  out_.acceleration_std_mps2 = std::sqrt(p(FusionFilter::kAcc, FusionFilter::kAcc));

  // A bias far from its calibrated value: the accelerometer has changed (it is still
  // used, the bias state compensates, but someone should look).
  if (std::abs(out_.accel_bias_mps2 - cfg_.sensors.accel_bias_mps2) > cfg_.motor.filter.accel_bias_limit_mps2)
    status |= status::kAccelFault;

  // Hall health: missing samples and sensors judged faulty.
  const std::uint32_t missing = all_halls_mask_ & ~sample.hall_valid_mask;
  const std::uint32_t flagged = missing | faulty_mask_;
  out_.hall_faulty_mask = faulty_mask_;
  status |= flagged << status::kHallFaultShift;
  int healthy = 0;
  for (int i = 0; i < kMaxHalls; ++i)
    if ((all_halls_mask_ & ~flagged) >> i & 1u) ++healthy;

  // The period is known only while the position is certain to well within a pitch.
  if (out_.position_std_m > cfg_.motor.magnet_pitch_m / 8.0) homed_ = false;
  if (homed_) status |= status::kHomed;
  if (status & (status::kAccelFault | (0xFFu << status::kHallFaultShift))) {
    status |= status::kSensorFault | status::kDegraded;
  }
  // One rejected fix is a spike the prediction bridges; two in a row mean the
  // prediction itself may be off, until the filter has followed the Halls again.
  // VALID: within the configured accuracy at the configured confidence.
  const auto& fc = cfg_.motor.filter;
  if (initialised_ && fc.valid_confidence_sigma * out_.position_std_m < fc.valid_position_accuracy_m &&
      fc.valid_confidence_sigma * out_.velocity_std_mps < fc.valid_velocity_accuracy_mps &&
      without_fix_in_row_ < cfg_.max_samples_without_fix && rejected_in_row_ < 2 && healthy >= min_healthy_ &&
      (temperature_checked || unread_place_) && !beyond_passes)
    status |= status::kValid;
  out_.status = status;
  return out_;
}

}  // namespace ve::core
