#include "canopen_io.hpp"

#include <linux/can.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <poll.h>
#include <pthread.h>
#include <sched.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>

#include <spdlog/spdlog.h>

#include "socketcan/can_receive.hpp"

namespace ve::app {

namespace {

std::int64_t now_ns(clockid_t clock) {
  timespec ts{};
  clock_gettime(clock, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1000000000LL + ts.tv_nsec;
}

}  // namespace

canopen::NodeConfig canopen_node_config(const config::AxisConfig& axis) {
  const config::CanopenConfig& c = axis.canopen;
  canopen::NodeConfig n;
  n.node_id = static_cast<std::uint8_t>(c.node_id);
  n.bitrate_kbps = static_cast<std::uint32_t>(c.bitrate_kbps);
  n.step_nm = c.measuring_step_nm;
  n.cyclic_timer_ms = static_cast<std::uint16_t>(c.cyclic_timer_ms);
  n.transmission_type = static_cast<std::uint8_t>(c.transmission_type);
  n.heartbeat_ms = static_cast<std::uint16_t>(c.heartbeat_ms);
  n.tpdo_mapping = {canopen::Mapped::position};
  if (c.map_speed) {
    if (c.speed_first)
      n.tpdo_mapping.insert(n.tpdo_mapping.begin(), canopen::Mapped::speed);
    else
      n.tpdo_mapping.push_back(canopen::Mapped::speed);
  }
  n.reverse = axis.output.direction < 0;  // 6000h bit 0 follows the axis' counting direction
  n.device_name = "virtual-encoder " + axis.name;
  n.software_version = VE_VERSION;
  n.serial = axis.id;
  return n;
}

CanopenNodeIo::CanopenNodeIo(const config::AxisConfig& axis, const canopen::SnapshotBox& box)
    : axis_name_(axis.name), interface_(axis.canopen.interface), box_(box), node_(canopen_node_config(axis), &box) {
  auto fail = [&](const std::string& what) {
    error_ = "axis '" + axis_name_ + "': canopen on '" + interface_ + "': " + what + ": " + std::strerror(errno);
    if (fd_ >= 0) ::close(fd_);
    fd_ = -1;
  };
  fd_ = ::socket(PF_CAN, SOCK_RAW | SOCK_CLOEXEC, CAN_RAW);
  if (fd_ < 0) { fail("socket(PF_CAN)"); return; }
  const int id = axis.canopen.node_id;
  // NMT, SYNC and this node's SDO requests only.
  const can_filter filters[] = {{0x000, CAN_SFF_MASK | CAN_EFF_FLAG | CAN_RTR_FLAG},
                                {0x080, CAN_SFF_MASK | CAN_EFF_FLAG | CAN_RTR_FLAG},
                                {static_cast<canid_t>(0x600 + id), CAN_SFF_MASK | CAN_EFF_FLAG | CAN_RTR_FLAG}};
  if (setsockopt(fd_, SOL_CAN_RAW, CAN_RAW_FILTER, filters, sizeof filters) < 0) { fail("CAN_RAW_FILTER"); return; }
  const int one = 1;
  if (setsockopt(fd_, SOL_SOCKET, SO_TIMESTAMPNS, &one, sizeof one) < 0) { fail("SO_TIMESTAMPNS"); return; }
  // Room for a burst of SYNC and SDO frames while this thread is not scheduled.
  const int buf = 1 << 20;
  if (setsockopt(fd_, SOL_SOCKET, SO_RCVBUFFORCE, &buf, sizeof buf) < 0)
    setsockopt(fd_, SOL_SOCKET, SO_RCVBUF, &buf, sizeof buf);
  const unsigned ifindex = if_nametoindex(interface_.c_str());
  if (ifindex == 0) { fail("no such interface"); return; }
  sockaddr_can addr{};
  addr.can_family = AF_CAN;
  addr.can_ifindex = static_cast<int>(ifindex);
  if (::bind(fd_, reinterpret_cast<sockaddr*>(&addr), sizeof addr) < 0) { fail("bind"); return; }
}

CanopenNodeIo::~CanopenNodeIo() {
  stop();
  if (fd_ >= 0) ::close(fd_);
}

std::string CanopenNodeIo::describe() const {
  const auto& c = node_.config();
  return "CiA 406 node " + std::to_string(c.node_id) + " on " + interface_ + " (step " + std::to_string(c.step_nm) +
         " nm, TPDO1 0x" + [&] {
           char b[8];
           std::snprintf(b, sizeof b, "%03X", 0x180 + c.node_id);
           return std::string(b);
         }() + ", transmission type " + std::to_string(c.transmission_type) + ", cyclic timer " +
         std::to_string(c.cyclic_timer_ms) + " ms, heartbeat " + std::to_string(c.heartbeat_ms) + " ms)";
}

std::string CanopenNodeIo::stats() const {
  return std::to_string(syncs_.load()) + " SYNC, " + std::to_string(tpdos_.load()) + " TPDO, " +
         std::to_string(sdo_.load()) + " SDO requests, " + std::to_string(emcy_.load()) + " EMCY, " +
         std::to_string(heartbeats_.load()) + " heartbeats, " + std::to_string(send_failures_.load()) +
         " frames not sent, " + std::to_string(sync_wait_expired_.load()) +
         " SYNCs answered before the estimate in progress (waited 2 ms)";
}

void CanopenNodeIo::start(const config::RealtimeConfig& realtime) {
  if (!ok() || thread_.joinable()) return;
  stopping_.store(false);
  const int priority = realtime.sample_thread_priority;
  const std::vector<int> cpus = realtime.cpus_for(axis_name_);
  thread_ = std::thread([this, priority, cpus] {
    pthread_setname_np(pthread_self(), ("ve-co-" + axis_name_).substr(0, 15).c_str());
    if (!cpus.empty()) {
      cpu_set_t set;
      CPU_ZERO(&set);
      for (int c : cpus) CPU_SET(c, &set);
      if (const int rc = pthread_setaffinity_np(pthread_self(), sizeof set, &set))
        spdlog::warn("axis '{}': canopen thread keeps its CPUs: {}", axis_name_, std::strerror(rc));
    }
    if (priority > 0) {
      sched_param p{};
      p.sched_priority = priority;
      if (const int rc = pthread_setschedparam(pthread_self(), SCHED_FIFO, &p))
        spdlog::warn("axis '{}': canopen thread without SCHED_FIFO {}: {}", axis_name_, priority, std::strerror(rc));
      else
        spdlog::info("axis '{}': canopen thread at SCHED_FIFO {}", axis_name_, priority);
    }
    loop();
  });
}

void CanopenNodeIo::stop() {
  stopping_.store(true);
  if (thread_.joinable()) thread_.join();
}

bool CanopenNodeIo::send(const canopen::Frame& f) {
  can_frame cf{};
  cf.can_id = f.id;
  cf.can_dlc = f.len;
  std::memcpy(cf.data, f.data.data(), f.len);
  // A full transmit queue (ENOBUFS) is retried briefly: a frame is dropped only
  // when the bus does not drain at all.
  for (int attempt = 0; attempt < 20; ++attempt) {
    if (::write(fd_, &cf, sizeof cf) == static_cast<ssize_t>(sizeof cf)) return true;
    if (errno != ENOBUFS && errno != EAGAIN && errno != EINTR) break;
    ::usleep(100);
  }
  send_failures_.fetch_add(1, std::memory_order_relaxed);
  return false;
}

void CanopenNodeIo::loop() {
  canopen::Outbox out;
  auto flush = [&] {
    for (int i = 0; i < out.count; ++i) send(out.frames[static_cast<std::size_t>(i)]);
    out.clear();
    const auto& c = node_.counters();
    syncs_.store(c.syncs, std::memory_order_relaxed);
    tpdos_.store(c.tpdos, std::memory_order_relaxed);
    sdo_.store(c.sdo_requests, std::memory_order_relaxed);
    emcy_.store(c.emcys, std::memory_order_relaxed);
    heartbeats_.store(c.heartbeats, std::memory_order_relaxed);
  };
  node_.start(now_ns(CLOCK_MONOTONIC), out);
  flush();
  // Alarms are looked at every few milliseconds (EMCY); timers when due.
  constexpr std::int64_t kAlarmPollNs = 5000000;
  while (!stopping_.load(std::memory_order_relaxed)) {
    const std::int64_t mono = now_ns(CLOCK_MONOTONIC);
    const std::int64_t due = std::min(node_.next_due_ns(), mono + kAlarmPollNs);
    const int timeout_ms = static_cast<int>(std::clamp<std::int64_t>((due - mono + 999999) / 1000000, 0, 50));
    pollfd p{fd_, POLLIN, 0};
    const int r = ::poll(&p, 1, timeout_ms);
    if (r > 0 && (p.revents & POLLIN)) {
      // Every frame waiting, each with its kernel reception time stamp.
      for (;;) {
        can_frame cf{};
        const socketcan::CanReceived rx = socketcan::receive_can_frame(fd_, &cf, sizeof cf);
        if (rx.bytes < static_cast<ssize_t>(sizeof cf)) break;
        std::int64_t rx_rt = rx.rx_realtime_ns;
        if (rx_rt == 0) rx_rt = now_ns(CLOCK_REALTIME);
        if ((cf.can_id & CAN_SFF_MASK) == 0x080) {
          // A SYNC received while the estimate of an earlier instant is still being
          // computed (a few microseconds): wait for it, so that the TPDO carries the
          // newest estimate handed over before the SYNC. Never longer than 2 ms; the
          // sample loop never waits for this thread.
          const std::int64_t give_up = now_ns(CLOCK_MONOTONIC) + 2000000;
          bool settled = box_.settled(rx_rt);
          while (!settled && now_ns(CLOCK_MONOTONIC) < give_up) {
            std::this_thread::yield();
            settled = box_.settled(rx_rt);
          }
          if (!settled) sync_wait_expired_.fetch_add(1, std::memory_order_relaxed);
        }
        canopen::Frame f;
        f.id = cf.can_id & CAN_SFF_MASK;
        f.len = std::min<std::uint8_t>(cf.can_dlc, 8);
        std::memcpy(f.data.data(), cf.data, f.len);
        node_.on_frame(f, rx_rt, now_ns(CLOCK_MONOTONIC), out);
        flush();
      }
    }
    node_.on_tick(now_ns(CLOCK_REALTIME), now_ns(CLOCK_MONOTONIC), out);
    flush();
  }
}

}  // namespace ve::app
