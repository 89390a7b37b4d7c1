// Calibration over DDS, served by `run`: commands arrive on ve/calibration_command,
// progress and results leave on ve/calibration_status (see dds_io.hpp).
//
// A START for a simulator axis runs what `virtual-encoder calibrate` runs live:
// the calibration motion on a second, non-realtime simulator of the axis (its
// exact position is the reference), core::identify_with_reference, and the
// atomic write of the calibration file and its report. It runs in one background
// worker thread at a lower scheduling priority (nice +10), never in an axis
// thread, so the state stream keeps its rate. One calibration per process at a
// time; a START meanwhile gets a FAILED "busy" status.
//
// The status message starts with the phase: "recording", "identifying",
// "writing", then "done", "failed" or "aborted" (state DONE / FAILED / ABORTED).
// An ABORT stops the recording within a few milliseconds; during the
// identification it takes effect when that returns. Either way nothing is
// written and an existing calibration file stays as it was.
//
// The running pipeline keeps the table it started with: a new calibration takes
// effect on the next start of `run`.
#pragma once

#include <atomic>
#include <cstdint>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "VirtualEncoder.h"
#include "config/machine_config.hpp"

namespace ve::app {

class CalibrationStatusWriter;

class CalibrationService {
 public:
  /// `machine` is copied; `status` must outlive the service.
  CalibrationService(const config::MachineConfig& machine, CalibrationStatusWriter& status);
  /// Aborts a running calibration and waits for the worker.
  ~CalibrationService();
  CalibrationService(const CalibrationService&) = delete;
  CalibrationService& operator=(const CalibrationService&) = delete;

  /// From the DDS listener thread: never blocks for long.
  void handle(const ve::dds::CalibrationCommand& command);

  /// Where a calibration of `axis` is written: its `calibration:` file, else
  /// calibration/<motor>.cal.yaml next to the machine file.
  static std::string output_path(const config::AxisConfig& axis, const std::string& machine_source);

 private:
  struct Job {
    config::AxisConfig axis;
    std::uint64_t request_id = 0;
    double sweep_speed_mps = 0.0;
    double sweep_acceleration_mps2 = 0.0;
  };
  void work(Job job);
  void publish(std::uint32_t axis_id, std::uint32_t state, std::uint64_t request_id, double progress,
               const std::string& message, const std::string& calibration_id = {}, double residual_m = 0.0);

  config::MachineConfig machine_;
  CalibrationStatusWriter& status_;
  std::mutex mutex_;          ///< handle() vs handle() and the destructor
  std::thread worker_;
  std::atomic<bool> running_{false};
  std::atomic<bool> abort_{false};
  std::uint32_t running_axis_ = 0;
  std::uint64_t running_request_ = 0;
};

}  // namespace ve::app
