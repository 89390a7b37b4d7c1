// What a machine file describes, after loading and validation. Plain structs;
// defaults in class. Only loader.cpp knows YAML.
#pragma once

#include <cstdint>
#include <string>
#include <utility>
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
  /// Publish every Nth estimate (1 = every sensor sample). The estimator still runs on
  /// every sample; this matches the stream to a drive whose control loop is slower than
  /// the sensor rate, and divides the DDS cost per axis by N.
  int publish_divider = 1;
};

/// How the axis learns which magnet period it is in at start-up.
struct HomingConfig {
  enum class Mode {
    none,              ///< position is relative to the period found at start-up; never HOMED
    startup_position,  ///< the axis is known to be within half a pitch of position_m at start-up
    /// relative at start-up; homed by matching the magnets' signature in the
    /// calibrated table over the first periods of motion
    signature,
  };
  Mode mode = Mode::startup_position;
  double position_m = 0.5;
  /// signature: where the position is kept at a clean shutdown, so that a restart at
  /// rest is homed at once (checked on the first motion); "" = not kept.
  std::string state_file;
};

/// `canopen:` of an axis: the axis is also a CiA 406 linear encoder node on a CAN
/// interface (component/canopen). Absent: no CANopen node.
struct CanopenConfig {
  bool enabled = false;             ///< the axis has a `canopen:` block
  std::string interface = "can0";   ///< network interface name (at most 15 characters)
  int node_id = 1;                  ///< 1..127, unique on its interface
  int bitrate_kbps = 1000;          ///< the bus' bit rate, for the EDS only (set with `ip link`)
  std::uint32_t measuring_step_nm = 1000;  ///< 6005h:01 / 6501h
  int cyclic_timer_ms = 0;          ///< 6200h; 0 = no cyclic TPDO
  int transmission_type = 254;      ///< 1800h:02: 1..240 every n-th SYNC, 254/255 cyclic
  int heartbeat_ms = 100;           ///< 1017h; 0 = none
  bool map_speed = false;           ///< TPDO1 maps 6030h:01 after 6004h
  bool speed_first = false;         ///< ... before it
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
  CanopenConfig canopen;
};

struct DdsConfig {
  int domain = 0;              ///< 0..232
  double deadline_ms = 5.0;    ///< offered deadline per axis instance; whole milliseconds
  std::string profiles_file;   ///< optional Fast DDS XML profiles (resolved path)
  /// The state writers (`state_writer`): `per_group` (the default) gives the axes one
  /// sample thread steps one keyed DataWriter, one instance each; `per_axis` gives every
  /// axis a DataWriter of its own (what a reader matched before: one state writer per
  /// axis), at the cost of one wake-up of Fast DDS's event thread per write with an
  /// offered deadline (docs/dds-interface.md).
  enum class StateWriters { per_group, per_axis };
  StateWriters state_writer = StateWriters::per_group;
  /// Fast DDS statistics topics to publish (what Fast DDS Monitor and other tools
  /// read), by name, e.g. HISTORY_LATENCY_TOPIC. Empty: none.
  std::vector<std::string> statistics;
};

/// `realtime:` in the machine file: how the sample threads are scheduled
/// and whether the process' memory is locked. All off by default.
struct RealtimeConfig {
  int sample_thread_priority = 0;  ///< SCHED_FIFO priority 1..99 of every sample thread; 0 = normal scheduling
  /// SCHED_FIFO priority 1..99 of Fast DDS's own threads in `run` (its event thread,
  /// which re-arms the offered deadline, and its receive threads), which take the
  /// writers' and the participant's locks a sample thread's write waits for: at normal
  /// priority they can hold a sample thread at FIFO priority for as long as the host
  /// keeps them off a CPU (priority inversion); at FIFO priority they take CPU time
  /// from everything at normal priority (a Discovery Server, the kernel's deferred
  /// network work) on a busy host. 0 (the default): normal scheduling. Must be below
  /// sample_thread_priority (docs/scale.md has the measurements).
  int dds_thread_priority = 0;
  /// CPUs every sample thread may run on (`cpu_affinity: [2, 3]`); empty = not pinned.
  std::vector<int> cpu_affinity;
  /// Per-axis CPUs (`cpu_affinity: {x: [1], y: [2]}`), by axis name; an axis not
  /// named here is not pinned. Used instead of cpu_affinity when not empty.
  std::vector<std::pair<std::string, std::vector<int>>> axis_cpu_affinity;
  bool lock_memory = false;  ///< mlockall(MCL_CURRENT | MCL_FUTURE) before the sample threads start
  /// false: a setting the process has no permission for is logged as a warning and
  /// the run goes on without it; true: `run` exits with 1 instead.
  bool required = false;
  /// How the axes' samples are paced (`sample_loop`): `shared` (the default) steps the
  /// simulated axes whose rates divide each other's and whose CPUs are the same in one
  /// thread, one wake-up per tick; `per_axis` gives every axis its own thread. Axes that
  /// wait for frames of their own (SocketCAN, replayed logs) always have their own.
  enum class SampleLoop { shared, per_axis };
  SampleLoop sample_loop = SampleLoop::shared;

  /// The CPUs of one axis' sample thread; empty = not pinned.
  const std::vector<int>& cpus_for(const std::string& axis) const {
    static const std::vector<int> none;
    if (axis_cpu_affinity.empty()) return cpu_affinity;
    for (const auto& [name, cpus] : axis_cpu_affinity)
      if (name == axis) return cpus;
    return none;
  }
  bool any() const { return sample_thread_priority > 0 || dds_thread_priority > 0 || !cpu_affinity.empty() || !axis_cpu_affinity.empty() || lock_memory; }
};

struct MachineConfig {
  std::string name = "machine";
  std::string source;  ///< file it came from (or "<embedded>/...")
  DdsConfig dds;
  RealtimeConfig realtime;
  std::vector<AxisConfig> axes;
};

}  // namespace ve::config
