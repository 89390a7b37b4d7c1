#include "socketcan/socketcan_source.hpp"

#include "socketcan/can_receive.hpp"

#include <linux/can.h>
#include <linux/can/error.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <poll.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>

namespace ve::socketcan {

namespace {

std::int64_t realtime_ns() {
  timespec ts{};
  clock_gettime(CLOCK_REALTIME, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1000000000LL + ts.tv_nsec;
}

std::string errno_text(const char* what, int e) {
  return std::string(what) + ": " + std::strerror(e) + " (errno " + std::to_string(e) + ")";
}

/// IFF_UP of `name`, through any socket; -1 when the interface does not exist.
int interface_up(int any_fd, const std::string& name) {
  ifreq ifr{};
  std::strncpy(ifr.ifr_name, name.c_str(), IFNAMSIZ - 1);
  if (ioctl(any_fd, SIOCGIFFLAGS, &ifr) < 0) return -1;
  return (ifr.ifr_flags & IFF_UP) ? 1 : 0;
}

}  // namespace

const char* to_string(BusState s) {
  switch (s) {
    case BusState::active: return "error-active";
    case BusState::warning: return "error-warning";
    case BusState::passive: return "error-passive";
    case BusState::bus_off: return "bus-off";
  }
  return "?";
}

SocketCanSource::SocketCanSource(SocketCanOptions options) : opt_(std::move(options)) {
  const LayoutProblem p = check_layout(opt_.layout);
  if (!p.message.empty()) {
    error_ = "socketcan: layout '" + opt_.layout.name + "': " + (p.where.empty() ? "" : p.where + ": ") + p.message;
    return;
  }
  if (opt_.interface.empty() || opt_.interface.size() >= IFNAMSIZ) {
    error_ = "socketcan: bad interface name '" + opt_.interface + "'";
    return;
  }
  if (opt_.ring_capacity < static_cast<std::size_t>(opt_.layout.samples_per_frame) * 4)
    opt_.ring_capacity = static_cast<std::size_t>(opt_.layout.samples_per_frame) * 4;
  ring_.resize(opt_.ring_capacity);
  std::string why;
  fd_ = open_socket(why);
  if (fd_ < 0) {
    error_ = why;
    return;
  }
  connected_.store(true);
  ok_ = true;
  thread_ = std::thread([this] { receive_loop(); });
}

SocketCanSource::~SocketCanSource() {
  stop();
  if (thread_.joinable()) thread_.join();
  close_socket();
}

int SocketCanSource::open_socket(std::string& error) {
  const int fd = ::socket(PF_CAN, SOCK_RAW | SOCK_NONBLOCK | SOCK_CLOEXEC, CAN_RAW);
  if (fd < 0) {
    const int e = errno;
    error = errno_text("socketcan: socket(PF_CAN, SOCK_RAW, CAN_RAW)", e);
    if (e == EAFNOSUPPORT || e == EPROTONOSUPPORT)
      error += ": this kernel has no SocketCAN (CONFIG_CAN / can-raw module missing; try `modprobe can-raw`, "
               "or run the tests in the VM of tests/vm)";
    return -1;
  }
  auto fail = [&](const char* what) {
    error = errno_text(what, errno);
    ::close(fd);
    return -1;
  };
  const int one = 1;
  if (opt_.layout.fd && setsockopt(fd, SOL_CAN_RAW, CAN_RAW_FD_FRAMES, &one, sizeof one) < 0)
    return fail("socketcan: setsockopt(CAN_RAW_FD_FRAMES) (kernel without CAN FD?)");
  // No id filter: the kernel's default for CAN_RAW (id 0, mask 0) delivers every data
  // frame, and the receive thread counts those of other ids (foreign id). A filter on
  // the layout's ids would drop them in the kernel, where nothing counts them, and a
  // node sending on a wrong id would look like a silent bus. Cost: one recvmsg and a
  // mask compare per frame of other nodes' traffic on a shared bus (at most about
  // 9,000 classic frames/s at 1 Mbit/s), drained in batches with the layout's frames.
  can_filter filter{};
  filter.can_id = 0;
  filter.can_mask = 0;
  if (setsockopt(fd, SOL_CAN_RAW, CAN_RAW_FILTER, &filter, sizeof filter) < 0)
    return fail("socketcan: setsockopt(CAN_RAW_FILTER)");
  const can_err_mask_t err_mask = CAN_ERR_MASK;
  if (setsockopt(fd, SOL_CAN_RAW, CAN_RAW_ERR_FILTER, &err_mask, sizeof err_mask) < 0)
    return fail("socketcan: setsockopt(CAN_RAW_ERR_FILTER)");
  if (setsockopt(fd, SOL_SOCKET, SO_TIMESTAMPNS, &one, sizeof one) < 0)
    return fail("socketcan: setsockopt(SO_TIMESTAMPNS)");
  (void)setsockopt(fd, SOL_SOCKET, SO_RXQ_OVFL, &one, sizeof one);  // best effort: drop counter
  const int rcvbuf = 1 << 20;
  // Room for a few hundred ms of frames; SO_RCVBUFFORCE (CAP_NET_ADMIN) beats rmem_max.
  if (setsockopt(fd, SOL_SOCKET, SO_RCVBUFFORCE, &rcvbuf, sizeof rcvbuf) < 0)
    (void)setsockopt(fd, SOL_SOCKET, SO_RCVBUF, &rcvbuf, sizeof rcvbuf);

  const unsigned index = if_nametoindex(opt_.interface.c_str());
  if (index == 0) {
    error = errno_text(("socketcan: interface '" + opt_.interface + "'").c_str(), errno);
    ::close(fd);
    return -1;
  }
  sockaddr_can addr{};
  addr.can_family = AF_CAN;
  addr.can_ifindex = static_cast<int>(index);
  if (bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) < 0)
    return fail(("socketcan: bind to '" + opt_.interface + "'").c_str());
  last_drop_count_ = 0;
  return fd;
}

void SocketCanSource::close_socket() {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
  connected_.store(false);
}

void SocketCanSource::set_error(std::string e) {
  std::lock_guard<std::mutex> lock(mu_);
  error_ = std::move(e);
}

std::string SocketCanSource::last_error() const {
  std::lock_guard<std::mutex> lock(mu_);
  return error_;
}

void SocketCanSource::stop() {
  {
    std::lock_guard<std::mutex> lock(mu_);
    stop_.store(true);
  }
  cv_.notify_all();
}

void SocketCanSource::receive_loop() {
  while (!stop_.load(std::memory_order_relaxed)) {
    if (fd_ < 0) {
      // Reopen once the interface exists and is up again.
      std::this_thread::sleep_for(std::chrono::milliseconds(opt_.reopen_interval_ms));
      const int probe = ::socket(PF_CAN, SOCK_RAW | SOCK_CLOEXEC, CAN_RAW);
      if (probe < 0) continue;
      const int up = interface_up(probe, opt_.interface);
      ::close(probe);
      if (up != 1) continue;
      std::string why;
      const int fd = open_socket(why);
      if (fd < 0) {
        set_error(why);
        continue;
      }
      fd_ = fd;
      connected_.store(true);
      c_.reconnects.fetch_add(1, std::memory_order_relaxed);
      set_error("");
      continue;
    }
    pollfd p{fd_, POLLIN, 0};
    const int r = ::poll(&p, 1, 50);
    if (r < 0) {
      if (errno == EINTR) continue;
      set_error(errno_text("socketcan: poll", errno));
      close_socket();
      continue;
    }
    if (r == 0) continue;
    if (!receive_some()) close_socket();
  }
}

bool SocketCanSource::receive_some() {
  // Drain what is queued; the socket is non-blocking.
  for (int n = 0; n < 256; ++n) {
    canfd_frame frame{};
    const CanReceived rx = receive_can_frame(fd_, &frame, sizeof frame);
    const ssize_t got = rx.bytes;
    if (got < 0) {
      const int e = rx.error;
      if (e == EAGAIN || e == EWOULDBLOCK || e == EINTR) return true;
      // ENETDOWN: the interface went down; ENODEV: it was removed. Reopen later.
      c_.socket_errors.fetch_add(1, std::memory_order_relaxed);
      set_error(errno_text(("socketcan: receive on '" + opt_.interface + "'").c_str(), e));
      return false;
    }
    if (rx.has_drops) {
      if (rx.drops > last_drop_count_)
        c_.kernel_drops.fetch_add(rx.drops - last_drop_count_, std::memory_order_relaxed);
      last_drop_count_ = rx.drops;
    }
    std::int64_t rx_ns = rx.rx_realtime_ns;
    if (rx_ns == 0) rx_ns = realtime_ns();
    if (got != static_cast<ssize_t>(CANFD_MTU) && got != static_cast<ssize_t>(CAN_MTU)) {
      // Neither a classic nor an FD frame: counted with the wrong-format frames.
      c_.bad_frames.fetch_add(1, std::memory_order_relaxed);
      c_.bad_format.fetch_add(1, std::memory_order_relaxed);
      continue;
    }
    process_frame(frame.can_id, got == static_cast<ssize_t>(CANFD_MTU), frame.data, frame.len, rx_ns);
  }
  return true;
}

void SocketCanSource::process_frame(std::uint32_t can_id, bool is_fd, const std::uint8_t* data, int len,
                                    std::int64_t rx_ns) {
  if (can_id & CAN_ERR_FLAG) {
    handle_error_frame(can_id & CAN_ERR_MASK, data, len);
    return;
  }
  if (can_id & CAN_RTR_FLAG) {  // a remote request carries no data
    c_.foreign_frames.fetch_add(1, std::memory_order_relaxed);
    c_.remote_frames.fetch_add(1, std::memory_order_relaxed);
    return;
  }
  const bool ext = (can_id & CAN_EFF_FLAG) != 0;
  const std::uint32_t id = can_id & (ext ? CAN_EFF_MASK : CAN_SFF_MASK);
  handle_frame(ext ? (id | 0x80000000u) : id, is_fd, data, len, rx_ns);
}

void SocketCanSource::handle_error_frame(std::uint32_t err, const std::uint8_t* data, int len) {
  c_.error_frames.fetch_add(1, std::memory_order_relaxed);
  const std::uint8_t ctrl = len > 1 ? data[1] : 0;
  bool classified = false;
  if (err & CAN_ERR_BUSOFF) {
    c_.bus_offs.fetch_add(1, std::memory_order_relaxed);
    bus_state_.store(static_cast<int>(BusState::bus_off));
    classified = true;
  }
  if (err & CAN_ERR_CRTL) {
    if (ctrl & (CAN_ERR_CRTL_RX_PASSIVE | CAN_ERR_CRTL_TX_PASSIVE)) {
      c_.bus_passives.fetch_add(1, std::memory_order_relaxed);
      if (!(err & CAN_ERR_BUSOFF)) bus_state_.store(static_cast<int>(BusState::passive));
      classified = true;
    } else if (ctrl & (CAN_ERR_CRTL_RX_WARNING | CAN_ERR_CRTL_TX_WARNING)) {
      c_.bus_warnings.fetch_add(1, std::memory_order_relaxed);
      if (!(err & CAN_ERR_BUSOFF)) bus_state_.store(static_cast<int>(BusState::warning));
      classified = true;
    }
    if (ctrl & CAN_ERR_CRTL_ACTIVE) {
      bus_state_.store(static_cast<int>(BusState::active));
      classified = true;
    }
  }
  if (err & CAN_ERR_RESTARTED) {
    bus_state_.store(static_cast<int>(BusState::active));
    classified = true;
  }
  if (!classified) c_.other_errors.fetch_add(1, std::memory_order_relaxed);
}

void SocketCanSource::handle_frame(std::uint32_t tagged_id, bool is_fd, const std::uint8_t* data, int len,
                                   std::int64_t rx_ns) {
  const bool ext = (tagged_id & 0x80000000u) != 0;
  const std::uint32_t id = tagged_id & 0x1FFFFFFFu;
  const CanLayout& l = opt_.layout;
  const DecodeStatus st = decode(l, id, ext, is_fd, data, len, frame_);
  if (st == DecodeStatus::wrong_id) {
    c_.foreign_frames.fetch_add(1, std::memory_order_relaxed);
    c_.foreign_id.fetch_add(1, std::memory_order_relaxed);
    c_.last_foreign_id.store(ext ? (id | CAN_EFF_FLAG) : id, std::memory_order_relaxed);
    return;
  }
  if (st != DecodeStatus::ok) {
    c_.bad_frames.fetch_add(1, std::memory_order_relaxed);
    (st == DecodeStatus::wrong_length ? c_.bad_length : c_.bad_format).fetch_add(1, std::memory_order_relaxed);
    return;
  }
  const std::int64_t period = l.sample_period_ns();
  const std::uint64_t n = static_cast<std::uint64_t>(l.samples_per_frame);
  // Frame counter, unwrapped.
  if (frame_.has_sequence) {
    const std::uint64_t wrap = l.sequence_wrap();
    if (!have_first_) {
      frame_index_ = frame_.sequence;
    } else {
      const std::uint64_t delta = (frame_.sequence - last_raw_seq_) & (wrap - 1);
      if (delta == 0) {
        c_.late_frames.fetch_add(1, std::memory_order_relaxed);
        return;
      }
      if (delta >= wrap / 2) {
        // Either an old frame (late / out of order) or a loss of more than half the
        // counter's range: the receive time decides.
        const std::int64_t frame_period = period * static_cast<std::int64_t>(n);
        const std::int64_t elapsed = rx_ns - last_rx_ns_;
        if (elapsed < static_cast<std::int64_t>(wrap / 2) * frame_period) {
          c_.late_frames.fetch_add(1, std::memory_order_relaxed);
          return;
        }
      }
      if (delta > 1) {
        c_.gaps.fetch_add(1, std::memory_order_relaxed);
        c_.lost_samples.fetch_add((delta - 1) * n, std::memory_order_relaxed);
      }
      frame_index_ += delta;
    }
    last_raw_seq_ = frame_.sequence;
  }
  // Node time, unwrapped (microseconds * 1000).
  std::int64_t node_ns = 0;
  if (frame_.has_node_time) {
    const SignalSpec& t = l.node_timestamp;
    const std::uint64_t raw = static_cast<std::uint64_t>(std::llround((frame_.node_time_us - t.offset) / t.scale)) &
                              ((std::uint64_t{1} << t.length) - 1);
    if (!have_first_) {
      node_unwrapped_ = static_cast<std::int64_t>(raw);
    } else {
      const std::uint64_t d = (raw - last_node_raw_) & ((std::uint64_t{1} << t.length) - 1);
      node_unwrapped_ += static_cast<std::int64_t>(d);
    }
    last_node_raw_ = raw;
    node_ns = std::llround((static_cast<double>(node_unwrapped_) * t.scale + t.offset) * 1e3);
  }
  if (!have_first_) {
    have_first_ = true;
    seq0_ = frame_index_ * n;
    // The frame left the node after its last sample.
    t0_ns_ = rx_ns - static_cast<std::int64_t>(n - 1) * period;
  }
  last_rx_ns_ = rx_ns;
  c_.frames.fetch_add(1, std::memory_order_relaxed);

  for (std::uint64_t k = 0; k < n; ++k) {
    core::RawSample& s = frame_.samples[k];
    if (frame_.has_sequence) {
      s.seq = frame_index_ * n + k;
    } else {
      s.seq = running_seq_++;
    }
    if (frame_.has_node_time)
      s.t_ns = node_ns + static_cast<std::int64_t>(k) * period;
    else if (frame_.has_sequence)
      s.t_ns = t0_ns_ + static_cast<std::int64_t>(s.seq - seq0_) * period;
    else
      s.t_ns = rx_ns - static_cast<std::int64_t>(n - 1 - k) * period;
    push(s);
  }
}

void SocketCanSource::push(const core::RawSample& s) {
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (count_ == ring_.size()) {
      c_.ring_overruns.fetch_add(1, std::memory_order_relaxed);
      return;
    }
    ring_[(head_ + count_) % ring_.size()] = s;
    ++count_;
  }
  c_.samples.fetch_add(1, std::memory_order_relaxed);
  cv_.notify_one();
}

drivers::ReadStatus SocketCanSource::read(core::RawSample& out) {
  if (!ok_) return drivers::ReadStatus::error;
  std::unique_lock<std::mutex> lock(mu_);
  const auto timeout = std::chrono::microseconds(static_cast<std::int64_t>(opt_.timeout_ms * 1000.0));
  if (!cv_.wait_for(lock, timeout, [this] { return count_ > 0 || stop_.load(std::memory_order_relaxed); }))
    return drivers::ReadStatus::timeout;
  if (stop_.load(std::memory_order_relaxed)) return drivers::ReadStatus::stopped;
  out = ring_[head_];
  head_ = (head_ + 1) % ring_.size();
  --count_;
  return drivers::ReadStatus::ok;
}

SocketCanCounters SocketCanSource::counters() const {
  SocketCanCounters r;
  auto ld = [](const std::atomic<std::uint64_t>& a) { return a.load(std::memory_order_relaxed); };
  r.frames = ld(c_.frames);
  r.samples = ld(c_.samples);
  r.gaps = ld(c_.gaps);
  r.lost_samples = ld(c_.lost_samples);
  r.late_frames = ld(c_.late_frames);
  r.bad_frames = ld(c_.bad_frames);
  r.bad_length = ld(c_.bad_length);
  r.bad_format = ld(c_.bad_format);
  r.foreign_frames = ld(c_.foreign_frames);
  r.foreign_id = ld(c_.foreign_id);
  r.remote_frames = ld(c_.remote_frames);
  r.last_foreign_id = c_.last_foreign_id.load(std::memory_order_relaxed);
  r.error_frames = ld(c_.error_frames);
  r.bus_warnings = ld(c_.bus_warnings);
  r.bus_passives = ld(c_.bus_passives);
  r.bus_offs = ld(c_.bus_offs);
  r.other_errors = ld(c_.other_errors);
  r.kernel_drops = ld(c_.kernel_drops);
  r.ring_overruns = ld(c_.ring_overruns);
  r.reconnects = ld(c_.reconnects);
  r.socket_errors = ld(c_.socket_errors);
  return r;
}

std::string SocketCanSource::stats() const {
  const SocketCanCounters c = counters();
  const CanLayout& l = opt_.layout;
  // Every frame the socket delivered and did not use is counted by its reason (late,
  // bad_length, bad_format, foreign: other ids and remote requests, error frames;
  // kernel queue and ring overflows). The socket has no kernel id filter, so every
  // frame on the bus is delivered; the last foreign id helps to find a node that
  // sends on a wrong one.
  char last[24] = "none";
  if (c.foreign_id > 0) {
    if (c.last_foreign_id & CAN_EFF_FLAG)
      std::snprintf(last, sizeof last, "0x%08X (extended)", c.last_foreign_id & CAN_EFF_MASK);
    else
      std::snprintf(last, sizeof last, "0x%03X", c.last_foreign_id & CAN_SFF_MASK);
  }
  char buf[896];
  std::snprintf(buf, sizeof buf,
                "frames=%llu samples=%llu gaps=%llu lost=%llu dropped: late=%llu bad=%llu (length=%llu "
                "format=%llu) foreign=%llu (id=%llu remote=%llu; last foreign id %s) kdrops=%llu overruns=%llu; "
                "errframes=%llu warn=%llu passive=%llu busoff=%llu other_err=%llu reconnects=%llu sockerr=%llu "
                "bus=%s; layout %s id 0x%X mask 0x%X, no kernel id filter (other ids are counted as foreign id)",
                (unsigned long long)c.frames, (unsigned long long)c.samples, (unsigned long long)c.gaps,
                (unsigned long long)c.lost_samples, (unsigned long long)c.late_frames, (unsigned long long)c.bad_frames,
                (unsigned long long)c.bad_length, (unsigned long long)c.bad_format,
                (unsigned long long)c.foreign_frames, (unsigned long long)c.foreign_id,
                (unsigned long long)c.remote_frames, last, (unsigned long long)c.kernel_drops,
                (unsigned long long)c.ring_overruns, (unsigned long long)c.error_frames,
                (unsigned long long)c.bus_warnings, (unsigned long long)c.bus_passives, (unsigned long long)c.bus_offs,
                (unsigned long long)c.other_errors, (unsigned long long)c.reconnects,
                (unsigned long long)c.socket_errors, to_string(bus_state()), l.extended_id ? "extended" : "standard",
                l.can_id, l.id_mask());
  return buf;
}

std::string SocketCanSource::describe() const {
  const CanLayout& l = opt_.layout;
  char ids[64];
  std::snprintf(ids, sizeof ids, "0x%X/0x%X", l.can_id, l.id_mask());
  return "socketcan(" + opt_.interface + ", " + (l.name.empty() ? std::string("layout") : l.name) + ", " +
         (l.fd ? "FD " : "classic ") + std::to_string(l.frame_length) + " B x" + std::to_string(l.samples_per_frame) +
         " samples, " + ids + ")";
}

}  // namespace ve::socketcan
