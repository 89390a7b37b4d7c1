// The subcommands of `virtual-encoder`. Each returns the process exit code:
// 0 success, 1 the job failed (e.g. check found problems, a write failed), 2 bad
// usage or input, 128 + the signal when SIGINT/SIGTERM ended it before its job was
// done (command_line.hpp, docs/command-line.md). The options come checked from
// parse_command_line (command_line.hpp).
#pragma once

#include <cstdint>
#include <optional>
#include <limits>
#include <string>

namespace ve::app {

struct RunOptions {
  std::string config;            ///< machine file; "" = the embedded simulator machine
  std::optional<int> domain;     ///< overrides dds.domain
  double duration_s = 0.0;       ///< stop after this long; 0 = until SIGINT/SIGTERM
  double status_period_s = 1.0;  ///< period of the status lines on the log
  /// Before starting the sources, wait up to this long for a first subscriber to
  /// match, so that it sees the motion from its first sample [s]. 0: start at once.
  double wait_for_subscriber_s = 0.0;
};
int run_command(const RunOptions& options);

struct CheckOptions {
  std::string config;
};
int check_command(const CheckOptions& options);

struct CalibrateOptions {
  std::string config;
  std::string axis;            ///< "" = the first axis
  std::string out;             ///< "" = the axis' calibration file, else calibration/<motor>.cal.yaml
  double sweep_speed_mps = 0.02;
  double sweep_acceleration_mps2 = 0.5;
  bool force = false;          ///< write the calibration even when its verdict is poor
  std::string log;             ///< raw log v1 with ref_position_m instead of a live simulator run
  /// Calibrate without the reference (also chosen when the log has no ref_position_m column).
  bool no_reference = false;
  /// Without a reference, one absolute delay must come from the hardware's design [us]; NaN: not given.
  double hall_delay_us = std::numeric_limits<double>::quiet_NaN();
  double accel_delay_us = std::numeric_limits<double>::quiet_NaN();
  /// Thermal calibration: each Hall sensor's temperature coefficients, from a
  /// recording some kelvin away from the existing calibration, added to it.
  bool thermal = false;
  /// Live thermal calibration on the simulator: how much warmer its motor runs [K].
  double sim_temperature_rise_k = 15.0;
};
int calibrate_command(const CalibrateOptions& options);

struct MonitorOptions {
  std::string config;              ///< to take the domain from; "" = embedded default
  std::optional<int> domain;
  double duration_s = 0.0;         ///< 0 = until SIGINT/SIGTERM
  bool csv = false;                ///< stream every sample as CSV instead of the live table
  double deadline_ms = 0.0;        ///< requested deadline; 0 = twice the configured offered deadline
  double refresh_s = 0.25;
};
int monitor_command(const MonitorOptions& options);

struct RecordOptions {
  std::string config;
  std::string axis;            ///< "" = the first axis
  std::string out;             ///< raw log v1 to write
  double duration_s = 10.0;    ///< 0 = until the source ends or SIGINT/SIGTERM
  bool fast = false;           ///< do not pace a simulated or replayed source in real time
  /// A source (a silent CAN bus) that delivers no first sample within this long fails the recording [s].
  double first_sample_timeout_s = 5.0;
};
int record_command(const RecordOptions& options);

struct EvaluateOptions {
  std::string config;
  std::string axis;
  std::string log;             ///< raw log v1: scored against its truth, else its ruler, else checked for consistency
  std::string calibration;     ///< overrides the axis' calibration file
  std::string estimates;       ///< optional CSV of the estimates per sample
  bool json = false;
  /// Overrides homing.position_m; must lie inside the axis' travel (checked once the machine file is loaded).
  std::optional<double> home_m;
  /// Against a ruler (ref_position_m, no truth): what is subtracted from the ruler's
  /// reading: "auto" (its mean difference from the estimate), "none" or metres.
  std::string ruler_offset = "auto";
  /// The ruler's resolution [um]; 0 = estimated as the smallest step between readings.
  double ruler_resolution_um = 0.0;
  /// Half-width of the Savitzky-Golay window that differentiates the ruler [samples]:
  /// 10 (21 samples, 5.25 ms at 4 kHz) balances a 1 um ruler's noise against the
  /// curvature a quadratic fit misses in the simulator's motion.
  int ruler_half_window = 10;
};
int evaluate_command(const EvaluateOptions& options);

// ---- sensor-node: SocketCAN sensor node emulator (issue 6) ----
struct SensorNodeOptions {
  std::string config;            ///< machine file whose axis has a sim driver; "" = embedded default
  std::string axis;              ///< "" = the first axis
  std::string can = "vcan0";     ///< interface to send on
  std::string layout;            ///< frame layout file (config/can/*.yaml)
  double duration_s = 0.0;       ///< 0 = until SIGINT/SIGTERM
  std::uint64_t drop_at = 0;     ///< fault injection: first frame (counter) not sent ...
  std::uint64_t drop_count = 0;  ///< ... and how many in a row; 0 = none
};
int sensor_node_command(const SensorNodeOptions& options);
// ---- end sensor-node ----

// ---- eds: the CANopen node's electronic data sheet ----
struct EdsOptions {
  std::string config;  ///< machine file; "" = the embedded simulator machine
  std::string axis;    ///< "" = the first axis with a `canopen:` block
  std::string out;     ///< "" = standard output
};
int eds_command(const EdsOptions& options);
// ---- end eds ----

}  // namespace ve::app
