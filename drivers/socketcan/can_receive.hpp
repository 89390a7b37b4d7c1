// One CAN frame from a CAN_RAW socket with what the kernel says about it: its
// reception time stamp (SO_TIMESTAMPNS, CLOCK_REALTIME) and the socket's count of
// frames dropped so far (SO_RXQ_OVFL), where the socket has those options on.
// Shared by the sensor-node driver, the CANopen node and the tests' CAN peers.
#pragma once

#include <sys/socket.h>
#include <sys/types.h>
#include <time.h>

#include <cerrno>
#include <cstddef>
#include <cstdint>
#include <cstring>

namespace ve::socketcan {

struct CanReceived {
  /// Bytes of the frame read (CAN_MTU or CANFD_MTU for a whole frame); -1 with
  /// `error` set when nothing could be read (EAGAIN: nothing waiting).
  ssize_t bytes = -1;
  int error = 0;
  /// Kernel reception time stamp [ns, CLOCK_REALTIME]; 0 when the kernel gave none.
  std::int64_t rx_realtime_ns = 0;
  /// The socket's running count of dropped frames, when the kernel reported it.
  bool has_drops = false;
  std::uint32_t drops = 0;
};

/// Reads one frame into `frame` (`size` bytes: a can_frame or canfd_frame) without
/// blocking, with its kernel time stamp and drop count.
inline CanReceived receive_can_frame(int fd, void* frame, std::size_t size) {
  CanReceived r;
  iovec iov{frame, size};
  alignas(cmsghdr) char control[CMSG_SPACE(sizeof(timespec)) + CMSG_SPACE(sizeof(std::uint32_t)) + 64];
  msghdr msg{};
  msg.msg_iov = &iov;
  msg.msg_iovlen = 1;
  msg.msg_control = control;
  msg.msg_controllen = sizeof control;
  r.bytes = ::recvmsg(fd, &msg, MSG_DONTWAIT);
  if (r.bytes < 0) {
    r.error = errno;
    return r;
  }
  for (cmsghdr* c = CMSG_FIRSTHDR(&msg); c; c = CMSG_NXTHDR(&msg, c)) {
    if (c->cmsg_level != SOL_SOCKET) continue;
    if (c->cmsg_type == SO_TIMESTAMPNS) {
      timespec ts{};
      std::memcpy(&ts, CMSG_DATA(c), sizeof ts);
      r.rx_realtime_ns = static_cast<std::int64_t>(ts.tv_sec) * 1000000000LL + ts.tv_nsec;
    } else if (c->cmsg_type == SO_RXQ_OVFL) {
      std::memcpy(&r.drops, CMSG_DATA(c), sizeof r.drops);
      r.has_drops = true;
    }
  }
  return r;
}

}  // namespace ve::socketcan
