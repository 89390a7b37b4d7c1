// Every frame the SocketCAN source is handed and does not use is counted by its
// reason, and stats() (what `run` logs for the axis) says so. The socket has no kernel
// id filter, so frames of other ids reach the source too and are counted as foreign
// id, with the last such id. Without a CAN kernel: the frames are
// fed to the receive thread's per-frame step of a source that has no socket (this
// host has no SocketCAN; the VM suite, tests/vm, covers the real socket).
#include <gtest/gtest.h>

#include <linux/can.h>
#include <linux/can/error.h>

#include <string>
#include <vector>

#include "socketcan/can_layout.hpp"
#include "config/can_layout_file.hpp"
#include "socketcan/socketcan_source.hpp"

using namespace ve::socketcan;

namespace {

CanLayout load(const std::string& rel) {
  CanLayout l;
  std::vector<ve::config::ConfigError> errors;
  EXPECT_TRUE(load_can_layout_file(std::string(VE_SOURCE_DIR) + "/" + rel, l, errors)) << ve::config::to_string(errors);
  return l;
}

TEST(SocketCanDropCount, EveryUnusedFrameIsCountedByReason) {
  SocketCanOptions opt;
  opt.interface = "vcan0";
  opt.layout = load("config/can/classic-4hall.yaml");
  SocketCanSource src(opt);
  if (src.ok()) GTEST_SKIP() << "this kernel has CAN and a vcan0: the receive thread owns the source (VM suite)";

  ve::core::RawSample s;
  s.hall_count = 4;
  s.hall_v = {2.5, 2.6, 2.4, 2.5};
  s.hall_valid_mask = 0xF;
  s.accel_mps2 = 0.1;
  FrameBytes good;
  ASSERT_EQ(encode(opt.layout, &s, 1, 0.0, good), 0);
  ASSERT_FALSE(good.extended);
  const std::int64_t t = 1'000'000'000;
  // Two good frames (sequence 1 and 2) are used.
  src.process_frame(good.id, false, good.data.data(), good.length, t);
  FrameBytes next;
  ASSERT_EQ(encode(opt.layout, &s, 2, 0.0, next), 0);
  src.process_frame(next.id, false, next.data.data(), next.length, t + 250'000);
  // The right id, 7 bytes: wrong length (x3).
  for (int i = 0; i < 3; ++i) src.process_frame(next.id, false, next.data.data(), 7, t + 300'000);
  // The right id as a CAN FD frame for a classic layout: wrong format (x2).
  for (int i = 0; i < 2; ++i) src.process_frame(next.id, true, next.data.data(), 8, t + 300'000);
  // A remote request for the layout's id: no data (foreign, remote).
  src.process_frame(next.id | CAN_RTR_FLAG, false, next.data.data(), 0, t + 300'000);
  // Ids that are not the layout's (foreign id): a standard one outside the mask, the
  // layout's id as an extended one, and one just outside the layout's range.
  src.process_frame(0x123, false, next.data.data(), 8, t + 300'000);
  src.process_frame(0x3FF, false, next.data.data(), 8, t + 300'000);
  src.process_frame(next.id | CAN_EFF_FLAG, false, next.data.data(), 8, t + 300'000);
  // An error frame (bus-off).
  std::uint8_t err[8] = {};
  src.process_frame(CAN_ERR_FLAG | CAN_ERR_BUSOFF, false, err, 8, t + 300'000);
  // The first good frame again: late (duplicate).
  src.process_frame(good.id, false, good.data.data(), good.length, t + 400'000);

  const SocketCanCounters c = src.counters();
  EXPECT_EQ(c.frames, 2u);
  EXPECT_EQ(c.bad_length, 3u);
  EXPECT_EQ(c.bad_format, 2u);
  EXPECT_EQ(c.bad_frames, 5u);
  EXPECT_EQ(c.foreign_frames, 4u);
  EXPECT_EQ(c.foreign_id, 3u);
  EXPECT_EQ(c.remote_frames, 1u);
  EXPECT_EQ(c.last_foreign_id, next.id | CAN_EFF_FLAG);
  EXPECT_EQ(c.error_frames, 1u);
  EXPECT_EQ(c.bus_offs, 1u);
  EXPECT_EQ(c.late_frames, 1u);

  const std::string line = src.stats();
  for (const char* part : {"frames=2 ", "late=1 ", "bad=5 (length=3 format=2)",
                           "foreign=4 (id=3 remote=1; last foreign id 0x00000402 (extended))", "errframes=1 ",
                           "busoff=1 ", "layout standard id 0x400 mask 0x700, no kernel id filter"})
    EXPECT_NE(line.find(part), std::string::npos) << "'" << part << "' not in: " << line;
  // The usable frames after all that still decode (a foreign frame changes no state).
  FrameBytes third;
  ASSERT_EQ(encode(opt.layout, &s, 3, 0.0, third), 0);
  src.process_frame(third.id, false, third.data.data(), third.length, t + 500'000);
  EXPECT_EQ(src.counters().frames, 3u);
  EXPECT_EQ(src.counters().gaps, 0u);
}

TEST(SocketCanDropCount, LastForeignIdIsTheStandardOneWhenThatCameLast) {
  SocketCanOptions opt;
  opt.interface = "vcan0";
  opt.layout = load("config/can/fd-4hall-x8.yaml");
  SocketCanSource src(opt);
  if (src.ok()) GTEST_SKIP() << "this kernel has CAN and a vcan0: the receive thread owns the source (VM suite)";
  std::uint8_t data[64] = {};
  EXPECT_NE(src.stats().find("last foreign id none"), std::string::npos) << src.stats();
  // The classic layout's ids on an FD layout's bus are foreign ids.
  for (std::uint32_t id = 0x400; id < 0x405; ++id) src.process_frame(id, false, data, 8, 1'000'000'000);
  src.process_frame(0x7FF, true, data, 64, 1'000'000'000);
  const SocketCanCounters c = src.counters();
  EXPECT_EQ(c.foreign_id, 6u);
  EXPECT_EQ(c.foreign_frames, 6u);
  EXPECT_EQ(c.remote_frames, 0u);
  EXPECT_EQ(c.frames, 0u);
  EXPECT_NE(src.stats().find("foreign=6 (id=6 remote=0; last foreign id 0x7FF)"), std::string::npos) << src.stats();
}

}  // namespace
