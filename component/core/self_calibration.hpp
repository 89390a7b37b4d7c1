// Calibration without a reference ruler: the Halls, the accelerometer and the
// nominal pitch are all there is.
//
// What it needs: the same recording as the calibration with a reference (a slow
// pass over the whole travel and back at a steady speed, plus fast motion), with
// no reference column. What it does:
//  1. Hall positions with the nominal table (sensors spaced as the motor file
//     says), unwrapped over the whole recording.
//  2. The slow passes are found in them (steady speed, one direction, at least a
//     second). Within a pass the carriage moves at a steady speed, so time is the
//     ruler between the magnets: each pass is fitted with one straight line
//     x = c + v t. The speed of that line is set by the nominal pitch over every
//     period the pass crosses (the track's placement errors do not accumulate);
//     every magnet period then gets its own pitch, at the scale of time, and each
//     sensor's table keeps every magnet's signature. Outside the passes (the
//     turnarounds, the fast motion) positions are the Hall positions solved with
//     the current table, shifted to join the passes continuously.
//  3. That position estimate stands in for the ruler in identify_with_reference
//     (tables, coil field, vibration); its tables and coil field re-solve the Hall
//     positions, and the loop repeats. The accelerometer's scale, bias and delay
//     are fitted here instead, against the Hall positions of the fast motion only
//     (never against stretches bridged with the accelerometer itself), with both
//     sides through the same derivative filter.
//  Every segment is placed on the table by the magnets' signatures with the
//  common mode (coil field) left out, scored over the whole segment at every
//  whole-period shift. Turnarounds between two passes are bridged by the
//  accelerometer, corrected in scale and bias to land on the next line. The loop
//  stops once it has converged, or once it only goes back and forth by less than
//  the verdict tolerates, and keeps that (last) iteration; one that does not
//  settle is reported as a problem.
//
// What it cannot know (and says so):
//  - The absolute zero: there is no reference mark. Position 0 is defined on the
//    magnet track itself, as home: the centre of sensor 0's first whole positive
//    half-wave from the near end of the sweep, i.e. the mean of its first rising
//    crossing of its table's mid level at least a quarter pitch past the lowest
//    position the sweep reached, and the falling crossing that follows (the mean
//    does not move with the sensor's offset voltage). The table is expressed in
//    that frame, so `run` with this calibration reports positions from home. The
//    feature is a property of the track and the sensor, found from the slow pass
//    only (no accelerometer is involved); where the carriage stood when the
//    recording started is no longer the zero (reaching it needs the accelerometer
//    bridged back from the first pass, good only to tens of um).
//  - The absolute timing. Every sensor in the recording could lag by the same
//    extra time and the recording would look the same, so only the accelerometer's
//    delay relative to the Halls is measured. One delay must be given from the
//    hardware's design (the Hall front end's filter, or the accelerometer's
//    data sheet): `hall_delay_s` or `accel_delay_s` below.
//  - The scale beyond the nominal pitch: the mean pitch over the travel is taken
//    as nominal; with N periods placed with errors of sigma each, the scale is
//    good to about sigma * sqrt(12) / (N^1.5 * pitch). sigma is measured from the
//    scatter of the periods' pitches, and that scale uncertainty goes into the
//    calibration (track_scale_std), so that the position's sigma says it.
// Pure computation on vectors held in memory; no I/O. The reference column of the
// segments, when there is one, is never read.
#pragma once

#include <limits>
#include <string>
#include <vector>

#include "hall_table.hpp"
#include "identification.hpp"
#include "motor.hpp"
#include "sample.hpp"

namespace ve::core {

struct SelfCalibrationConfig {
  IdentificationConfig identification;
  /// Most outer iterations (solve positions with the table, rebuild the table);
  /// they stop earlier once converged: the estimate moved by at most converged_m
  /// RMS and the accelerometer's scale by at most converged_scale since the last.
  int iterations = 12;
  double converged_m = 0.05e-6;
  double converged_scale = 2e-4;
  /// The verdict calls iterations that did not settle a problem only when the last
  /// still moved the estimate by more than this (RMS) [m]: below, they go back and
  /// forth between neighbouring solutions by a tenth of what a calibration without
  /// a ruler is good to (about 1 um beyond the track's own scale).
  double unsettled_limit_m = 0.5e-6;
  /// They also stop once they go back and forth below that limit: the change (at
  /// most unsettled_limit_m) was more than stalled_ratio of the one before, this
  /// many iterations in a row, and the accelerometer's scale moved by at most
  /// converged_scale. Converging iterations shrink the change severalfold each time;
  /// ones that have stopped shrinking it only trade one neighbouring solution for
  /// another. 0: run on to `iterations`.
  int stalled_iterations = 2;
  double stalled_ratio = 0.9;
  /// The one absolute delay the recording cannot tell: give the Halls' (from the
  /// front end's filter design) or the accelerometer's (its data sheet). When both
  /// are NaN the Hall delay is taken as 0 and the report says so.
  double hall_delay_s = std::numeric_limits<double>::quiet_NaN();
  double accel_delay_s = std::numeric_limits<double>::quiet_NaN();
  /// A slow pass: at least this long at steady speed [s].
  double min_pass_s = 1.0;
  /// Samples left out at either end of a pass (the speed settling) [s].
  double pass_margin_s = 0.05;
  /// Half-width of the derivative window applied to the self-made position [s];
  /// 0: the identification's own.
  double derivative_half_window_s = 0.0;
  /// Half-width of the derivative window through which the accelerometer's scale
  /// and delay are fitted against the self-made position [s]: long enough that the
  /// Hall solve's errors at the magnet frequency do not pass as acceleration, short
  /// against the calibration motion (about 1 Hz).
  double accel_scale_half_window_s = 0.025;
};

struct SelfCalibrationReport {
  IdentificationReport identification;  ///< the final identification against the self-made position
  int passes_forward = 0;
  int passes_backward = 0;
  double forward_speed_mps = 0.0;       ///< mean speed of the forward passes
  double backward_speed_mps = 0.0;
  double swept_m = 0.0;                 ///< length covered by the slow passes (far end minus near end)
  int periods = 0;                      ///< whole magnet periods over the swept length
  /// How far apart the pass lines and the Hall positions are where they join,
  /// after the last iteration (RMS over the joins) [m]; large: the speed was not steady.
  double join_mismatch_m = 0.0;
  /// Straight-line fit residual of the Hall positions within the passes, RMS [m]
  /// (with the final table: what a speed ripple would show as).
  double pass_line_residual_m = 0.0;
  /// Each magnet period's pitch along the travel (sensor 0's rising crossings) [m].
  std::vector<double> period_start_m;
  std::vector<double> period_pitch_m;
  /// The magnets' placement scatter, one sigma, from the pitches' (a pitch is the
  /// difference of two placements: sigma of the pitches / sqrt 2) [m], and what it
  /// leaves of the track's scale: a least-squares line through N magnets placed
  /// that well has a slope good to sigma / (pitch sqrt(N (N^2 - 1) / 12)). That is
  /// the calibration's scale (it is the track's), written as track_scale_std.
  double magnet_placement_std_m = 0.0;
  double track_scale_std = 0.0;
  /// Each sensor's position on the carriage relative to sensor 0 (from the tables) [m].
  std::vector<double> sensor_offset_m;
  /// Home (position 0 of the calibration, see the top of this file) measured from
  /// where the carriage stood at the start of the sweep's recording [m]: about where
  /// to look for the feature on a machine; its accuracy is the accelerometer
  /// bridge's (tens of um), the calibration's zero itself does not depend on it.
  double home_from_sweep_start_m = 0.0;
  /// Sensor 0's rising and falling mid-level crossings that define home, in the
  /// calibration's frame [m] (their mean is 0).
  double home_rising_m = 0.0, home_falling_m = 0.0;
  /// One line saying what position 0 is, for the report.
  std::string zero_definition;
  /// Where the Hall delay came from ("given", "from the accelerometer delay given", "assumed 0").
  std::string hall_delay_source;
  double hall_delay_reproduced_s = 0.0; ///< what forward/backward gave against the self-made position (a check)
  std::vector<std::string> iterations;  ///< one line per iteration: what it found
  bool converged = false;               ///< the iterations settled (see SelfCalibrationConfig)
  /// They stopped going back and forth below unsettled_limit_m without settling
  /// (SelfCalibrationConfig::stalled_iterations); converged is false then.
  bool stalled = false;
  double last_change_m = 0.0;           ///< how far the last iteration moved the estimate, RMS [m]
};

/// Identifies table and sensor model without a reference. False (with `error`)
/// when the recording cannot give a result (no slow pass in each direction, ...);
/// otherwise true, with report.identification.good telling whether to trust it.
bool identify_without_reference(const MotorConfig& motor, const std::vector<ReferenceSegment>& segments,
                                const SelfCalibrationConfig& config, Calibration& out, SelfCalibrationReport& report,
                                std::string& error);

/// Home on a table: the mean of sensor 0's first rising crossing of its row's
/// mid level (0.5 (min + max)) at or after `from_m` and the falling crossing
/// after it. False when the table has none.
bool table_home(const HallTable& table, double from_m, double& home_m, double& rising_m, double& falling_m);

/// Each sensor's offset on the carriage relative to sensor 0, and each magnet
/// period's start and pitch, from a table's crossings of the mid level.
void table_geometry(const MotorConfig& motor, const HallTable& table, std::vector<double>& sensor_offset_m,
                    std::vector<double>& period_start_m, std::vector<double>& period_pitch_m);

}  // namespace ve::core
