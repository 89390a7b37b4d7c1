// `virtual-encoder sensor-node`: a stand-in for a sensor node's firmware. Runs the
// simulated motor of a machine file's axis in real time and sends its samples on a
// SocketCAN interface in a frame layout (config/can/*.yaml), for demos and the VM tests.
#include <linux/can.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <vector>

#include "commands.hpp"
#include "config/loader.hpp"
#include "signals.hpp"
#include "sim/sim_source.hpp"
#include "socketcan/can_layout.hpp"
#include "config/can_layout_file.hpp"

namespace ve::app {

namespace {

int open_tx_socket(const std::string& iface, bool fd_frames, std::string& error) {
  const int s = ::socket(PF_CAN, SOCK_RAW | SOCK_CLOEXEC, CAN_RAW);
  if (s < 0) {
    error = std::string("socket(PF_CAN, SOCK_RAW, CAN_RAW): ") + std::strerror(errno);
    if (errno == EAFNOSUPPORT) error += " (this kernel has no SocketCAN; see tests/vm for a VM that has)";
    return -1;
  }
  const int one = 1;
  if (fd_frames && setsockopt(s, SOL_CAN_RAW, CAN_RAW_FD_FRAMES, &one, sizeof one) < 0) {
    error = std::string("setsockopt(CAN_RAW_FD_FRAMES): ") + std::strerror(errno);
    ::close(s);
    return -1;
  }
  (void)setsockopt(s, SOL_CAN_RAW, CAN_RAW_FILTER, nullptr, 0);  // send only: receive nothing
  const unsigned index = if_nametoindex(iface.c_str());
  if (index == 0) {
    error = "interface '" + iface + "': " + std::strerror(errno);
    ::close(s);
    return -1;
  }
  sockaddr_can addr{};
  addr.can_family = AF_CAN;
  addr.can_ifindex = static_cast<int>(index);
  if (bind(s, reinterpret_cast<sockaddr*>(&addr), sizeof addr) < 0) {
    error = "bind to '" + iface + "': " + std::strerror(errno);
    ::close(s);
    return -1;
  }
  return s;
}

/// Sends one frame; false on an error (counted by the caller; the node keeps going).
bool send_frame(int s, const socketcan::FrameBytes& f, int& err) {
  canfd_frame frame{};
  frame.can_id = f.id | (f.extended ? CAN_EFF_FLAG : 0u);
  frame.len = f.length;
  std::memcpy(frame.data, f.data.data(), f.length);
  const std::size_t size = f.fd ? CANFD_MTU : CAN_MTU;
  for (int attempt = 0; attempt < 20; ++attempt) {
    const ssize_t n = ::write(s, &frame, size);
    if (n == static_cast<ssize_t>(size)) return true;
    err = errno;
    if (err != ENOBUFS && err != EAGAIN && err != EINTR) return false;
    timespec ts{0, 200000};  // the tx queue is full: wait a little
    nanosleep(&ts, nullptr);
  }
  return false;
}

}  // namespace

int sensor_node_command(const SensorNodeOptions& options) {
  auto result = options.config.empty() ? config::load_embedded_default() : config::load_machine_file(options.config);
  for (const auto& e : result.errors) std::fprintf(stderr, "%s\n", e.to_string().c_str());
  if (!result.ok()) return 2;
  const config::MachineConfig& machine = result.config;
  const config::AxisConfig* axis = nullptr;
  for (const auto& a : machine.axes)
    if (options.axis.empty() ? true : a.name == options.axis) {
      axis = &a;
      break;
    }
  if (!axis) {
    std::fprintf(stderr, "no axis '%s' in %s\n", options.axis.c_str(), machine.source.c_str());
    return 2;
  }
  if (axis->driver.kind != config::DriverConfig::Kind::sim) {
    std::fprintf(stderr, "sensor-node: axis '%s' of %s has no sim driver; the emulator simulates the motor\n",
                 axis->name.c_str(), machine.source.c_str());
    return 2;
  }
  socketcan::CanLayout layout;
  std::vector<config::ConfigError> errors;
  if (!socketcan::load_can_layout_file(options.layout, layout, errors)) {
    std::fprintf(stderr, "%s", config::to_string(errors).c_str());
    return 2;
  }
  if (layout.hall_count != axis->motor.hall.count || std::abs(layout.sample_rate_hz - axis->motor.sample_rate_hz) > 1e-6) {
    std::fprintf(stderr, "sensor-node: layout %s (%d Halls, %g Hz) does not fit motor '%s' (%d Halls, %g Hz)\n",
                 options.layout.c_str(), layout.hall_count, layout.sample_rate_hz, axis->motor.name.c_str(),
                 axis->motor.hall.count, axis->motor.sample_rate_hz);
    return 2;
  }
  sim::SimConfig cfg = axis->driver.sim;
  cfg.realtime = true;
  cfg.duration_s = options.duration_s;
  // A layout with a temperature signal: the node has a temperature sensor, so the
  // simulator reports one (its own noise stream: the Hall and accelerometer values
  // do not change).
  if (layout.temperature.present) cfg.temperature.report = true;
  sim::SimSource sim(axis->motor, cfg);
  if (!sim.ok()) {
    std::fprintf(stderr, "sensor-node: %s\n", sim.last_error().c_str());
    return 2;
  }
  std::string error;
  const int s = open_tx_socket(options.can, layout.fd, error);
  if (s < 0) {
    std::fprintf(stderr, "sensor-node: %s\n", error.c_str());
    return 1;
  }
  std::fprintf(stderr, "sensor-node: %s axis %s -> %s, layout %s (%s, %d B, %d sample(s)/frame, id 0x%X)%s\n",
               machine.name.c_str(), axis->name.c_str(), options.can.c_str(), layout.name.c_str(),
               layout.fd ? "CAN FD" : "classic", layout.frame_length, layout.samples_per_frame, layout.can_id,
               options.drop_count > 0 ? " with a burst of dropped frames" : "");

  std::array<core::RawSample, socketcan::kMaxSamplesPerFrame> batch;
  socketcan::FrameBytes frame;
  std::uint64_t frame_index = 0, sent = 0, dropped = 0, tx_errors = 0, saturated = 0;
  int last_err = 0;
  bool done = false;
  while (!done) {
    int k = 0;
    for (; k < layout.samples_per_frame; ++k) {
      auto st = sim.read(batch[static_cast<std::size_t>(k)]);
      // A no_samples fault: the node is silent (sends nothing) until its next sample.
      while (st == drivers::ReadStatus::timeout && !wait_for_termination(0.0))
        st = sim.read(batch[static_cast<std::size_t>(k)]);
      if (st != drivers::ReadStatus::ok) {
        done = true;
        break;
      }
    }
    if (k < layout.samples_per_frame) break;  // a partial frame is not sent
    const double node_us = static_cast<double>(batch[0].t_ns) * 1e-3;
    saturated += static_cast<std::uint64_t>(socketcan::encode(layout, batch.data(), frame_index, node_us, frame));
    const bool drop = options.drop_count > 0 && frame_index >= options.drop_at &&
                      frame_index < options.drop_at + options.drop_count;
    ++frame_index;
    if (drop) {
      ++dropped;
      continue;
    }
    if (send_frame(s, frame, last_err))
      ++sent;
    else
      ++tx_errors;
    if ((frame_index & 63) == 0 && wait_for_termination(0.0)) break;
  }
  ::close(s);
  std::fprintf(stderr, "sensor-node: %llu frames (%llu samples) sent, %llu dropped on purpose, %llu send errors%s%s, "
               "%llu values saturated\n",
               (unsigned long long)sent, (unsigned long long)(sent * static_cast<std::uint64_t>(layout.samples_per_frame)),
               (unsigned long long)dropped, (unsigned long long)tx_errors, tx_errors ? " (last: " : "",
               tx_errors ? (std::string(std::strerror(last_err)) + ")").c_str() : "", (unsigned long long)saturated);
  return sent > 0 ? 0 : 1;
}

}  // namespace ve::app
