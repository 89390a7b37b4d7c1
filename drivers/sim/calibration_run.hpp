// A calibration run on the simulated motor: what a commissioning engineer does on
// a real machine with a reference ruler, here with the simulator's exact position
// as the ruler. Two segments on the same magnet track (same track_seed): a slow
// sweep over the whole travel and back (the table and the Hall delay), then a few
// seconds of fast multisine motion (coil field, accelerometer scale, bias, delay).
#pragma once

#include <atomic>
#include <functional>
#include <string>
#include <vector>

#include "core/identification.hpp"
#include "core/motor.hpp"
#include "sim/sim_config.hpp"

namespace ve::sim {

struct CalibrationRunConfig {
  double sweep_speed_mps = 0.02;               ///< the slow sweep over the whole travel and back [m/s]
  double sweep_acceleration_mps2 = 0.5;        ///< its acceleration at each end [m/s^2]
  double dynamic_duration_s = 5.0;             ///< then this long of fast multisine motion [s]
  double dynamic_max_velocity_mps = 2.0;       ///< its peak speed (lowered until it fits a short travel)
  double dynamic_max_acceleration_mps2 = 10.0; ///< its peak acceleration [m/s^2]
};

/// Simulates the calibration motion on the motor and sensors of `base` (its
/// imperfections and track; the profile is replaced) and returns the recording.
/// `progress` (optional) receives 0..1. `cancel` (optional) is checked every
/// 1000 samples: when it is set the run stops, returns false and sets `error`
/// to kCalibrationRunCancelled.
inline constexpr const char* kCalibrationRunCancelled = "cancelled";
bool record_calibration_run(const core::MotorConfig& motor, const SimConfig& base, const CalibrationRunConfig& run,
                            std::vector<core::ReferenceSegment>& segments, std::string& error,
                            const std::function<void(double)>& progress = {},
                            const std::atomic<bool>* cancel = nullptr);

}  // namespace ve::sim
