// A CiA 406 node of one axis on SocketCAN: a thin owner of the CAN_RAW socket and of
// the node's thread. The protocol is component/canopen (canopen::Node); this file only
// moves frames and passes their kernel reception time stamps (the SYNC instant).
// The axis' sample loop hands its estimate over through a canopen::SnapshotBox and
// never waits for this thread.
#pragma once

#include <atomic>
#include <memory>
#include <string>
#include <thread>

#include "canopen/node.hpp"
#include "canopen/snapshot.hpp"
#include "config/machine_config.hpp"

namespace ve::app {

/// The node configuration of an axis' `canopen:` block.
canopen::NodeConfig canopen_node_config(const config::AxisConfig& axis);

class CanopenNodeIo {
 public:
  /// Opens the interface; ok() false with last_error() naming the axis when it cannot.
  CanopenNodeIo(const config::AxisConfig& axis, const canopen::SnapshotBox& box);
  ~CanopenNodeIo();
  CanopenNodeIo(const CanopenNodeIo&) = delete;
  CanopenNodeIo& operator=(const CanopenNodeIo&) = delete;

  bool ok() const { return fd_ >= 0; }
  const std::string& last_error() const { return error_; }
  /// Starts the node's thread (boot-up message, then pre-operational), named
  /// "ve-co-AXIS"; with `realtime` giving the sample threads a SCHED_FIFO priority, the
  /// node's thread takes the same priority and the axis' CPUs (a SYNC is answered
  /// ahead of DDS), and says so, or why not, in the log.
  void start(const config::RealtimeConfig& realtime);
  void stop();
  std::string describe() const;
  /// Counters for the log at the end of a run.
  std::string stats() const;

 private:
  void loop();
  bool send(const canopen::Frame& f);

  std::string axis_name_;
  std::string interface_;
  const canopen::SnapshotBox& box_;
  canopen::Node node_;
  int fd_ = -1;
  std::string error_;
  std::thread thread_;
  std::atomic<bool> stopping_{false};
  std::atomic<std::uint64_t> send_failures_{0};
  std::atomic<std::uint64_t> syncs_{0}, tpdos_{0}, sdo_{0}, emcy_{0}, heartbeats_{0};
  /// SYNCs answered without waiting for the estimate still being computed (2 ms passed).
  std::atomic<std::uint64_t> sync_wait_expired_{0};
};

}  // namespace ve::app
