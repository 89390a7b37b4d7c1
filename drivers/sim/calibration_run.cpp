#include "sim/calibration_run.hpp"

#include "sim/motion_profile.hpp"
#include "sim/sim_source.hpp"

namespace ve::sim {

namespace {

bool record(const core::MotorConfig& motor, const SimConfig& cfg, double duration_s, core::ReferenceSegment& seg,
            std::string& error, const std::function<void(double)>& progress, const std::atomic<bool>* cancel,
            double done, double share) {
  SimSource source(motor, cfg);
  if (!source.ok()) {
    error = source.last_error();
    return false;
  }
  const auto n = static_cast<std::size_t>(duration_s * motor.sample_rate_hz);
  seg.samples.reserve(n);
  seg.reference_m.reserve(n);
  core::RawSample s;
  while (seg.samples.size() < n) {
    if (seg.samples.size() % 1000 == 0) {
      if (cancel != nullptr && cancel->load(std::memory_order_relaxed)) {
        error = kCalibrationRunCancelled;
        return false;
      }
      if (progress) progress(done + share * static_cast<double>(seg.samples.size()) / static_cast<double>(n));
    }
    if (source.read(s) != drivers::ReadStatus::ok) {
      error = "the simulator stopped after " + std::to_string(seg.samples.size()) + " samples: " + source.last_error();
      return false;
    }
    double x = 0.0;
    source.reference_position(x);
    seg.samples.push_back(s);
    seg.reference_m.push_back(x);
  }
  return true;
}

}  // namespace

bool record_calibration_run(const core::MotorConfig& motor, const SimConfig& base, const CalibrationRunConfig& run,
                            std::vector<core::ReferenceSegment>& segments, std::string& error,
                            const std::function<void(double)>& progress, const std::atomic<bool>* cancel) {
  segments.assign(2, core::ReferenceSegment{});
  SimConfig sweep = base;
  sweep.realtime = false;
  sweep.duration_s = 0.0;
  sweep.profile = MotionProfileConfig{};
  sweep.profile.kind = MotionProfileConfig::Kind::shuttle;
  sweep.profile.start_m = 0.0;
  sweep.profile.min_m = 0.0;
  sweep.profile.max_m = motor.travel_m;
  sweep.profile.max_velocity_mps = run.sweep_speed_mps;
  sweep.profile.max_acceleration_mps2 = run.sweep_acceleration_mps2;
  const double sweep_s = 2.0 * (motor.travel_m / run.sweep_speed_mps + run.sweep_speed_mps / run.sweep_acceleration_mps2);

  SimConfig dynamic = base;
  dynamic.realtime = false;
  dynamic.duration_s = 0.0;
  dynamic.noise_seed = base.noise_seed + 1;
  dynamic.profile = MotionProfileConfig{};
  dynamic.profile.kind = MotionProfileConfig::Kind::multisine;
  dynamic.profile.start_m = 0.5 * motor.travel_m;
  dynamic.profile.min_m = 0.05 * motor.travel_m;
  dynamic.profile.max_m = 0.95 * motor.travel_m;
  dynamic.profile.max_velocity_mps = run.dynamic_max_velocity_mps;
  dynamic.profile.max_acceleration_mps2 = run.dynamic_max_acceleration_mps2;

  // A short motor cannot hold the full multisine: lower its speed until it fits.
  for (int i = 0; i < 20 && !MotionProfile::create(dynamic.profile, motor.travel_m); ++i)
    dynamic.profile.max_velocity_mps *= 0.8;

  const double total = sweep_s + run.dynamic_duration_s;
  if (!record(motor, sweep, sweep_s, segments[0], error, progress, cancel, 0.0, sweep_s / total)) return false;
  if (!record(motor, dynamic, run.dynamic_duration_s, segments[1], error, progress, cancel, sweep_s / total,
              run.dynamic_duration_s / total))
    return false;
  if (progress) progress(1.0);
  return true;
}

}  // namespace ve::sim
