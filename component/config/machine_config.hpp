// What a machine file describes, after loading and validation. Plain structs;
// defaults in class. Only loader.cpp knows YAML.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "core/motor.hpp"
#include "sim/sim_config.hpp"
#include "socketcan/can_layout.hpp"  // socketcan driver (issue 6)

namespace ve::config {

// ---- socketcan driver (issue 6) ----
/// `driver: {type: socketcan, interface: vcan0, layout: ../can/classic-4hall.yaml, timeout_ms: 20}`
struct SocketCanConfig {
  std::string interface = "can0";  ///< network interface name (at most 15 characters)
  std::string layout_file;         ///< resolved path of the frame layout file
  socketcan::CanLayout layout;     ///< loaded and checked from layout_file
  double timeout_ms = 20.0;        ///< read() returns timeout after this long without a sample
};
// ---- end socketcan ----

struct DriverConfig {
  enum class Kind { sim, replay, socketcan };
  Kind kind = Kind::sim;
  sim::SimConfig sim;       ///< kind == sim
  std::string replay_path;  ///< kind == replay: raw log (resolved path)
  bool replay_realtime = true;  ///< kind == replay: pace the rows by their time stamps
  SocketCanConfig socketcan;    ///< kind == socketcan
};

/// Encoder-equivalent output scaling: counts = direction * position_m * counts_per_m + preset_counts.
struct OutputConfig {
  double counts_per_m = 1e7;  ///< 0.1 um per count
  int direction = 1;          ///< +1 or -1
  std::int64_t preset_counts = 0;
};

/// How the axis learns which magnet period it is in at start-up.
struct HomingConfig {
  enum class Mode {
    none,              ///< position is relative to the period found at start-up; never HOMED
    startup_position,  ///< the axis is known to be within half a pitch of position_m at start-up
  };
  Mode mode = Mode::startup_position;
  double position_m = 0.5;
};

struct AxisConfig {
  std::string name;         ///< e.g. "x"; at most 15 characters
  std::uint32_t id = 0;     ///< DDS instance key; unique per machine
  std::string motor_file;   ///< resolved path of the motor file ("" when embedded)
  core::MotorConfig motor;
  DriverConfig driver;
  std::string calibration_file;  ///< resolved path; "" = nominal table, not calibrated
  OutputConfig output;
  HomingConfig homing;
};

struct DdsConfig {
  int domain = 0;              ///< 0..232
  double deadline_ms = 5.0;    ///< offered deadline per axis instance; whole milliseconds
  std::string profiles_file;   ///< optional Fast DDS XML profiles (resolved path)
  /// Fast DDS statistics topics to publish (what Fast DDS Monitor and other tools
  /// read), by name, e.g. HISTORY_LATENCY_TOPIC. Empty: none.
  std::vector<std::string> statistics;
};

struct MachineConfig {
  std::string name = "machine";
  std::string source;  ///< file it came from (or "<embedded>/...")
  DdsConfig dds;
  std::vector<AxisConfig> axes;
};

}  // namespace ve::config
