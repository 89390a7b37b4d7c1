#include "pipeline.hpp"

#include <cmath>
#include <utility>

#include "status.hpp"

namespace ve::core {

namespace {
// Above this position sigma the estimate is still converging (start-up,
// re-acquisition) and is not fit for a position or velocity loop.
constexpr double kValidPositionStdM = 50e-6;
constexpr double kValidVelocityStdMps = 10e-3;
}  // namespace

AxisPipeline::AxisPipeline(const PipelineConfig& config, HallTable table)
    : cfg_(config),
      hall_(config.motor, std::move(table)),
      kf_(config.motor.sample_period_s(), config.motor.filter.jerk_std_mps3),
      period_ns_(static_cast<std::int64_t>(std::llround(1e9 / config.motor.sample_rate_hz))) {
  const double an = config.motor.accelerometer.noise_mps2;
  accel_var_ = an * an;
}

bool AxisPipeline::initialise(const RawSample& sample) {
  const double p = cfg_.motor.magnet_pitch_m;
  HallFix fix;
  if (cfg_.start_position_known) {
    fix = hall_.acquire(sample, cfg_.start_position_m - 0.5 * p, cfg_.start_position_m + 0.5 * p);
  } else {
    // Relative: any period looks alike on an ideal track; take the first ones.
    fix = hall_.acquire(sample, hall_.table().start_m + p, hall_.table().start_m + 2.0 * p);
  }
  if (!fix.ok) return false;
  const auto& f = cfg_.motor.filter;
  KinematicKalman::Vec x;
  x << fix.position_m, 0.0, sample.accel_valid ? sample.accel_mps2 : 0.0;
  KinematicKalman::Mat p0 = KinematicKalman::Mat::Zero();
  p0(0, 0) = fix.variance_m2;
  p0(1, 1) = f.initial_velocity_std_mps * f.initial_velocity_std_mps;
  p0(2, 2) = sample.accel_valid ? accel_var_ : f.initial_acceleration_std_mps2 * f.initial_acceleration_std_mps2;
  kf_.reset(x, p0);
  homed_ = cfg_.start_position_known;
  rejected_in_row_ = 0;
  return true;
}

const EncoderEstimate& AxisPipeline::step(const RawSample& sample) {
  std::uint32_t status = cfg_.calibrated ? status::kCalibrated : 0u;
  out_.t_ns = sample.t_ns;
  out_.seq = sample.seq;
  out_.samples_skipped = 0;

  // Timing: predict once per nominal period elapsed, so dropped samples are
  // bridged by prediction; a long silence restarts the filter.
  int steps = 1;
  if (initialised_) {
    const std::int64_t dt = sample.t_ns - last_t_ns_;
    const std::int64_t n = (dt + period_ns_ / 2) / period_ns_;
    if (n <= 0 || static_cast<double>(dt) * 1e-9 > cfg_.max_gap_s) {
      initialised_ = false;
    } else {
      steps = static_cast<int>(n);
      out_.samples_skipped = static_cast<std::uint32_t>(n - 1);
    }
  }
  last_t_ns_ = sample.t_ns;

  for (int i = 0; i < sample.hall_count && i < kMaxHalls; ++i)
    if (!(sample.hall_valid_mask >> i & 1u)) status |= status::hall_fault(i);
  if (!sample.accel_valid || std::abs(sample.accel_mps2) >= cfg_.motor.accelerometer.range_mps2)
    status |= status::kAccelFault;

  if (!initialised_) {
    initialised_ = initialise(sample);
    if (!initialised_) {
      out_.status = status | status::kHallRejected;
      return out_;
    }
  } else {
    for (int i = 0; i < steps; ++i) kf_.predict();
  }

  const HallFix fix = hall_.solve(sample, kf_.state()(KinematicKalman::kPos));
  bool applied = false;
  out_.hall_sensors_used = fix.sensors_used;
  if (fix.ok) {
    out_.hall_position_m = fix.position_m;
    out_.hall_std_m = std::sqrt(fix.variance_m2);
    out_.hall_innovation_sigma = kf_.update(KinematicKalman::kPos, fix.position_m, fix.variance_m2,
                                            cfg_.motor.filter.gate_sigma, applied);
    if (fix.out_of_table) status |= status::kOutOfTravel;
  }
  if (applied) {
    rejected_in_row_ = 0;
  } else {
    status |= status::kHallRejected;
    if (++rejected_in_row_ >= cfg_.max_rejected_in_row) initialised_ = false;
  }
  if (!(status & status::kAccelFault)) {
    bool used = false;
    kf_.update(KinematicKalman::kAcc, sample.accel_mps2, accel_var_, 0.0, used);
  }

  const auto& x = kf_.state();
  const auto& p = kf_.covariance();
  out_.position_m = x(KinematicKalman::kPos);
  out_.velocity_mps = x(KinematicKalman::kVel);
  out_.acceleration_mps2 = x(KinematicKalman::kAcc);
  out_.position_std_m = std::sqrt(p(0, 0));
  out_.velocity_std_mps = std::sqrt(p(1, 1));
  out_.acceleration_std_mps2 = std::sqrt(p(2, 2));

  if (homed_) status |= status::kHomed;
  if (status & (status::kAccelFault | (0xFFu << status::kHallFaultShift))) {
    status |= status::kSensorFault | status::kDegraded;
  }
  if (initialised_ && out_.position_std_m < kValidPositionStdM && out_.velocity_std_mps < kValidVelocityStdMps &&
      rejected_in_row_ < cfg_.max_rejected_in_row / 2)
    status |= status::kValid;
  out_.status = status;
  return out_;
}

}  // namespace ve::core
