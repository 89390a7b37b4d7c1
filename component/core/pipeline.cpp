#include "pipeline.hpp"

#include <cmath>
#include <utility>

#include "status.hpp"

namespace ve::core {

namespace {
// Above these the estimate is still converging (start-up, re-acquisition) and is
// not fit for a position or velocity loop.
constexpr double kValidPositionStdM = 50e-6;
constexpr double kValidVelocityStdMps = 10e-3;
}  // namespace

AxisPipeline::AxisPipeline(const PipelineConfig& config, HallTable table)
    : cfg_(config),
      hall_(config.motor, std::move(table)),
      kf_(config.motor.sample_period_s(), config.motor.filter, config.sensors),
      period_ns_(static_cast<std::int64_t>(std::llround(1e9 / config.motor.sample_rate_hz))) {
  const double an = config.motor.accelerometer.noise_mps2;
  accel_var_ = an * an;
}

bool AxisPipeline::acquire(const RawSample& sample) {
  const double p = cfg_.motor.magnet_pitch_m;
  double lo, hi;
  bool homed;
  if (started_) {
    // Re-acquisition: search half a pitch either side of where the filter says the
    // carriage is. The period is still known only if that is certain to well
    // within a pitch.
    const double x = kf_.state()(FusionFilter::kPos);
    lo = x - 0.5 * p;
    hi = x + 0.5 * p;
    homed = homed_ && std::sqrt(kf_.covariance()(FusionFilter::kPos, FusionFilter::kPos)) < p / 8.0;
  } else if (cfg_.start_position_known) {
    lo = cfg_.start_position_m - 0.5 * p;
    hi = cfg_.start_position_m + 0.5 * p;
    homed = true;
  } else {
    // Relative: any period looks alike on an ideal track; take the second one.
    lo = hall_.table().start_m + p;
    hi = hall_.table().start_m + 2.0 * p;
    homed = false;
  }
  const HallFix fix = hall_.acquire(sample, lo, hi);
  if (!fix.ok) return false;
  kf_.reset(fix.position_m, fix.variance_m2, accel_reading(sample), accel_usable(sample));
  homed_ = homed;
  started_ = true;
  rejected_in_row_ = 0;
  without_fix_in_row_ = 0;
  return true;
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

const EncoderEstimate& AxisPipeline::step(const RawSample& sample) {
  std::uint32_t status = cfg_.calibrated ? status::kCalibrated : 0u;
  out_.t_ns = sample.t_ns;
  out_.seq = sample.seq;
  out_.samples_skipped = 0;

  for (int i = 0; i < sample.hall_count && i < kMaxHalls; ++i)
    if (!(sample.hall_valid_mask >> i & 1u)) status |= status::hall_fault(i);
  if (!accel_usable(sample)) status |= status::kAccelFault;

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
  out_.hall_sensors_used = 0;
  if (!initialised_) {
    initialised_ = acquire(sample);
    if (!initialised_) {
      out_.status = status | status::kHallRejected;
      return out_;
    }
    applied = true;
  } else {
    for (int i = 0; i < steps; ++i) kf_.predict();

    // The Halls saw the track at t - hall_delay; start the search there. The coil
    // field adds the same offset to every sensor, in proportion to the force.
    const auto& xp = kf_.state();
    const double guess = xp(FusionFilter::kPos) - cfg_.sensors.hall_delay_s * xp(FusionFilter::kVel);
    const double common_mode = cfg_.sensors.coil_field_v_per_mps2 * xp(FusionFilter::kAcc);
    const HallFix fix = hall_.solve(sample, guess, common_mode);
    out_.hall_sensors_used = fix.sensors_used;
    if (fix.ok) {
      without_fix_in_row_ = 0;
      out_.hall_position_m = fix.position_m;
      out_.hall_std_m = std::sqrt(fix.variance_m2);
      if (fix.out_of_table) status |= status::kOutOfTravel;
      const double gate = cfg_.motor.filter.gate_sigma;
      out_.hall_innovation_sigma = kf_.update_hall(fix.position_m, fix.variance_m2, gate, applied);
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
        kf_.inflate(nu * nu, 4.0 * nu * nu / (span_s * span_s), 4.0 * nu * nu / (span_s * span_s * span_s * span_s));
        out_.hall_innovation_sigma = kf_.update_hall(fix.position_m, fix.variance_m2, 0.0, applied);
        rejected_in_row_ = 0;
      }
    } else if (++without_fix_in_row_ >= cfg_.max_samples_without_fix) {
      initialised_ = false;  // re-acquire near the prediction on the next sample
    }
  }
  if (!applied) status |= status::kHallRejected;

  if (!(status & status::kAccelFault)) {
    bool used = false;
    const bool frame = use_frame(sample);
    const double r = frame ? 2.0 * accel_var_ : accel_var_;
    // Spike rejection by size: a sigma gate would also reject real acceleration steps.
    const double spike_sigma = cfg_.motor.filter.accel_spike_mps2 / std::sqrt(r + kf_.covariance()(FusionFilter::kAcc, FusionFilter::kAcc));
    kf_.update_accel(accel_reading(sample), r, spike_sigma, used);
  }

  const auto& x = kf_.state();
  const auto& p = kf_.covariance();
  out_.position_m = x(FusionFilter::kPos);
  out_.velocity_mps = x(FusionFilter::kVel);
  out_.acceleration_mps2 = x(FusionFilter::kAcc);
  out_.accel_bias_mps2 = x(FusionFilter::kBias);
  out_.accel_scale = x(FusionFilter::kScale);
  out_.position_std_m = std::sqrt(p(FusionFilter::kPos, FusionFilter::kPos));
  out_.velocity_std_mps = std::sqrt(p(FusionFilter::kVel, FusionFilter::kVel));
  out_.acceleration_std_mps2 = std::sqrt(p(FusionFilter::kAcc, FusionFilter::kAcc));

  // The period is known only while the position is certain to well within a pitch.
  if (out_.position_std_m > cfg_.motor.magnet_pitch_m / 8.0) homed_ = false;
  if (homed_) status |= status::kHomed;
  if (status & (status::kAccelFault | (0xFFu << status::kHallFaultShift))) {
    status |= status::kSensorFault | status::kDegraded;
  }
  // One rejected fix is a spike the prediction bridges; two in a row mean the
  // prediction itself may be off, until the filter has followed the Halls again.
  if (initialised_ && out_.position_std_m < kValidPositionStdM && out_.velocity_std_mps < kValidVelocityStdMps &&
      without_fix_in_row_ < cfg_.max_samples_without_fix / 2 && rejected_in_row_ < 2)
    status |= status::kValid;
  out_.status = status;
  return out_;
}

}  // namespace ve::core
