// Sensor source reading a sensor node over SocketCAN (CAN_RAW, classic CAN or CAN FD).
//
// A receive thread owns the socket (non-blocking, poll), decodes each frame
// (can_layout.hpp) and hands the samples to read() through a fixed-size ring (no
// allocation per sample). The socket has no kernel id filter: a frame whose id is not
// the layout's reaches the thread and is counted (foreign id, with the last such id),
// so a node sending on a wrong id shows in the counters instead of as a silent bus.
// Time base:
//  - frames with a node timestamp: t_ns = node time (unwrapped) + k * period;
//  - else with a sequence counter: t_ns = t0 + (seq - seq0) * period, t0 the kernel
//    receive timestamp (SO_TIMESTAMPNS, CLOCK_REALTIME) of the first frame minus the
//    samples it batches, so lost frames show up as jumps in t_ns (the pipeline then
//    predicts through them) and bus jitter does not enter the time base;
//  - else: the kernel receive timestamp of each frame, sample k at ts - (n-1-k) * period.
// RawSample::seq is the unwrapped counter (frame counter * samples_per_frame + k).
// Faults never throw: sequence gaps, late/duplicate frames, frames of the wrong
// length or format, error frames (bus warning / passive / off), the interface going
// down (the socket is reopened once it is up again), a silent bus (read() timeout).
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "core/sample.hpp"
#include "socketcan/can_layout.hpp"
#include "source.hpp"

namespace ve::socketcan {

struct SocketCanOptions {
  std::string interface = "can0";
  CanLayout layout;
  double timeout_ms = 20.0;       ///< read() gives up after this long without a sample
  std::size_t ring_capacity = 8192;  ///< samples buffered between the thread and read()
  int reopen_interval_ms = 100;   ///< retry period while the interface is down or gone
};

enum class BusState { active, warning, passive, bus_off };
const char* to_string(BusState s);

/// Counters since construction; each is read atomically (not as a consistent set).
struct SocketCanCounters {
  std::uint64_t frames = 0;         ///< frames of this layout decoded
  std::uint64_t samples = 0;        ///< samples queued for read()
  std::uint64_t gaps = 0;           ///< sequence jumps (one per burst of lost frames)
  std::uint64_t lost_samples = 0;   ///< samples missing in those jumps
  std::uint64_t late_frames = 0;    ///< duplicate or out-of-order frames (dropped)
  std::uint64_t bad_frames = 0;     ///< right id, wrong length or format (dropped): bad_length + bad_format
  std::uint64_t bad_length = 0;     ///< ... payload not the layout's frame_length
  std::uint64_t bad_format = 0;     ///< ... classic/FD mismatch, or neither a classic nor an FD frame
  /// Frames that carry no data of this layout (dropped): foreign_id + remote_frames.
  std::uint64_t foreign_frames = 0;
  /// ... data frames whose id is not the layout's (can_id / id_mask, standard or
  /// extended): another node's traffic on a shared bus, or a node on a wrong id.
  std::uint64_t foreign_id = 0;
  std::uint64_t remote_frames = 0;  ///< ... remote requests (RTR), any id
  /// The id of the last foreign-id frame, with CAN_EFF_FLAG for an extended one
  /// (meaningful when foreign_id > 0).
  std::uint32_t last_foreign_id = 0;
  std::uint64_t error_frames = 0;   ///< CAN error frames (CAN_ERR_FLAG)
  std::uint64_t bus_warnings = 0;   ///< error frames reporting error-warning (rx or tx)
  std::uint64_t bus_passives = 0;   ///< ... error-passive
  std::uint64_t bus_offs = 0;       ///< ... bus-off
  std::uint64_t other_errors = 0;   ///< protocol, ack, arbitration, transceiver, overflow...
  std::uint64_t kernel_drops = 0;   ///< frames the socket queue dropped (SO_RXQ_OVFL)
  std::uint64_t ring_overruns = 0;  ///< samples dropped because read() fell behind
  std::uint64_t reconnects = 0;     ///< successful reopens after the interface went away
  std::uint64_t socket_errors = 0;  ///< receive errors (ENETDOWN, ENODEV...) that closed the socket
};

class SocketCanSource final : public drivers::SensorSource {
 public:
  /// Opens, filters and binds the socket, then starts the receive thread. Never
  /// throws: when the kernel has no CAN (EAFNOSUPPORT), the interface does not exist
  /// or the layout is invalid, ok() is false, last_error() says why and read()
  /// returns ReadStatus::error. An interface that exists but is down is fine: the
  /// source waits for it.
  explicit SocketCanSource(SocketCanOptions options);
  ~SocketCanSource() override;

  bool ok() const { return ok_; }

  /// The next sample, waiting up to timeout_ms: ok, timeout (silent bus), stopped.
  drivers::ReadStatus read(core::RawSample& out) override;
  void stop() override;
  /// "socketcan(vcan0, classic-4hall, classic 8 B x1 sample, 0x400/0x700)".
  std::string describe() const override;
  std::string last_error() const override;

  SocketCanCounters counters() const;
  std::uint64_t frames() const { return c_.frames.load(std::memory_order_relaxed); }
  std::uint64_t gaps() const { return c_.gaps.load(std::memory_order_relaxed); }
  std::uint64_t lost_samples() const { return c_.lost_samples.load(std::memory_order_relaxed); }
  std::uint64_t bad_frames() const { return c_.bad_frames.load(std::memory_order_relaxed); }
  std::uint64_t error_frames() const { return c_.error_frames.load(std::memory_order_relaxed); }
  std::uint64_t reconnects() const { return c_.reconnects.load(std::memory_order_relaxed); }
  BusState bus_state() const { return static_cast<BusState>(bus_state_.load(std::memory_order_relaxed)); }
  /// True while the socket is open and bound (false while the interface is down/gone).
  bool connected() const { return connected_.load(std::memory_order_relaxed); }
  /// One line with every counter and the dropped frames by reason (foreign ones with
  /// the last foreign id), for logs.
  std::string stats() const override;
  /// The receive thread, which read() waits for.
  std::vector<pthread_t> helper_threads() override {
    if (!thread_.joinable()) return {};
    return {thread_.native_handle()};
  }

  /// The receive thread's step for one frame the socket delivered: `can_id` with the
  /// kernel's CAN_EFF/RTR/ERR_FLAG bits, as in struct can_frame. Public so that the
  /// counting can be tested without a CAN kernel; call it only on a source whose
  /// receive thread does not run (ok() false).
  void process_frame(std::uint32_t can_id, bool fd, const std::uint8_t* data, int len, std::int64_t rx_ns);

  const SocketCanOptions& options() const { return opt_; }

 private:
  struct AtomicCounters {
    std::atomic<std::uint64_t> frames{0}, samples{0}, gaps{0}, lost_samples{0}, late_frames{0}, bad_frames{0},
        bad_length{0}, bad_format{0}, foreign_frames{0}, foreign_id{0}, remote_frames{0}, error_frames{0},
        bus_warnings{0}, bus_passives{0}, bus_offs{0}, other_errors{0}, kernel_drops{0}, ring_overruns{0},
        reconnects{0}, socket_errors{0};
    std::atomic<std::uint32_t> last_foreign_id{0};
  };

  int open_socket(std::string& error);  // fd or -1
  void close_socket();
  void receive_loop();
  bool receive_some();  // false: socket failed and was closed
  void handle_frame(std::uint32_t can_id, bool fd, const std::uint8_t* data, int len, std::int64_t rx_ns);
  void handle_error_frame(std::uint32_t can_id, const std::uint8_t* data, int len);
  void push(const core::RawSample& s);
  void set_error(std::string e);

  SocketCanOptions opt_;
  bool ok_ = false;
  int fd_ = -1;
  std::thread thread_;
  std::atomic<bool> stop_{false};
  std::atomic<bool> connected_{false};
  std::atomic<int> bus_state_{0};
  AtomicCounters c_;
  std::uint64_t last_drop_count_ = 0;

  // Sequence / time-base state (receive thread only).
  bool have_first_ = false;
  std::uint64_t last_raw_seq_ = 0;
  std::uint64_t frame_index_ = 0;    // unwrapped counter
  std::int64_t last_rx_ns_ = 0;
  std::int64_t t0_ns_ = 0;           // t of sample seq0
  std::uint64_t seq0_ = 0;
  std::uint64_t running_seq_ = 0;    // no counter in the layout
  std::uint64_t last_node_raw_ = 0;  // node timestamp unwrapping [raw counts]
  std::int64_t node_unwrapped_ = 0;
  DecodedFrame frame_;

  // Ring between the thread and read().
  mutable std::mutex mu_;
  std::condition_variable cv_;
  std::vector<core::RawSample> ring_;
  std::size_t head_ = 0, count_ = 0;
  std::string error_;  // guarded by mu_
};

}  // namespace ve::socketcan
