// A population of simulated motors: seeded random draws over the ranges a real
// catalogue of permanent-magnet linear motors spans (pitch, sensor count and
// spacing, sample rate, delays, tolerances, ADC, travel). Each draw gives two
// descriptions of one motor:
//  - `datasheet`: what a commissioning engineer writes into the motor file from
//    the data sheet (nominal pitch, sensor spacing, amplitude, noise, ADC, ...);
//    the estimator is given this and nothing else;
//  - `hardware` + `sim`: the motor as built (its real amplitude and noise, and
//    every tolerance, delay and coupling as simulator imperfections), which only
//    the simulator knows.
// Accuracy claims are then made on motors nobody tuned the estimator on.
#pragma once

#include <cstdint>
#include <string>

#include "core/motor.hpp"
#include "sim/sim_config.hpp"

namespace ve::sim {

/// The ranges draws come from (uniform unless said otherwise).
struct PopulationRanges {
  double pitch_min_m = 0.008, pitch_max_m = 0.040;
  int halls_min = 3, halls_max = 8;
  double rate_min_hz = 2000.0, rate_max_hz = 10000.0;
  double travel_min_m = 0.2, travel_max_m = 2.0;
  double hall_delay_max_s = 100e-6;
  double accel_delay_max_s = 600e-6;
  double magnet_placement_max_m = 50e-6;   ///< one-sigma tolerance drawn in [0, this]
  double magnet_strength_max = 0.05;
  double sensor_placement_max_m = 100e-6;  ///< twice the shipped realistic motor's
  double sensor_gain_max = 0.06;
  double sensor_offset_max_v = 0.040;
  double coil_field_max_v_per_mps2 = 0.003;
  double third_harmonic_max = 0.08;
  /// Real Hall amplitude relative to the data sheet's (a batch, the air gap).
  double amplitude_datasheet_error_max = 0.10;
};

struct PopulationMotor {
  std::uint64_t seed = 0;
  core::MotorConfig datasheet;  ///< what the motor file holds: nominal values only
  core::MotorConfig hardware;   ///< the motor as built (the simulator's motor)
  SimConfig sim;                ///< its imperfections and track; profile left at its default
  /// One line describing the draw, for reports.
  std::string summary() const;
};

/// Draws motor `seed` (deterministic: the same seed gives the same motor on every
/// host). `tuning` supplies the estimator's filter settings (the motor file
/// template's), which are not a property of the motor. Every draw is a motor whose
/// sensor array sees the position everywhere (at every magnet phase at least one
/// sensor is out of saturation).
PopulationMotor draw_population_motor(std::uint64_t seed, const core::FilterConfig& tuning,
                                      const PopulationRanges& ranges = {});

/// Fewest Hall sensors out of saturation at any magnet phase of this nominal motor
/// (0: a blind spot), and the fraction of phases with at least two.
void hall_coverage(const core::MotorConfig& motor, int& min_unsaturated, double& fraction_two_or_more);

}  // namespace ve::sim
