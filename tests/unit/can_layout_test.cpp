// Frame layout of the SocketCAN driver (issue 6): bit access in both byte orders,
// encode/decode round trips, known byte patterns, sign extension, saturation,
// wrong id/length rejection, layout checks and the YAML layout files.
#include <gtest/gtest.h>

#include <cmath>
#include <string>
#include <vector>

#include "socketcan/can_layout.hpp"
#include "config/can_layout_file.hpp"
#include "socketcan/socketcan_source.hpp"

using namespace ve::socketcan;
using ve::core::RawSample;

namespace {

constexpr double kHallLsb = 5.0 / 4095.0;

SignalSpec sig(int start, int length, ByteOrder order = ByteOrder::little_endian, bool is_signed = false,
               double scale = 1.0, double offset = 0.0) {
  SignalSpec s;
  s.present = true;
  s.start_bit = start;
  s.length = length;
  s.order = order;
  s.is_signed = is_signed;
  s.scale = scale;
  s.offset = offset;
  return s;
}

CanLayout load(const std::string& rel) {
  CanLayout l;
  std::vector<ve::config::ConfigError> errors;
  EXPECT_TRUE(load_can_layout_file(std::string(VE_SOURCE_DIR) + "/" + rel, l, errors)) << ve::config::to_string(errors);
  return l;
}

RawSample sample(double h0, double h1, double h2, double h3, double a) {
  RawSample s;
  s.hall_count = 4;
  s.hall_v = {h0, h1, h2, h3};
  s.hall_valid_mask = 0xF;
  s.accel_mps2 = a;
  s.accel_valid = true;
  return s;
}

}  // namespace

struct BitCase {
  const char* name;
  int start, length;
  ByteOrder order;
  std::uint64_t raw;
  std::vector<std::uint8_t> bytes;  // expected frame (8 bytes)
};

TEST(CanLayoutBits, KnownPatterns) {
  const BitCase cases[] = {
      {"le byte 0", 0, 8, ByteOrder::little_endian, 0xAB, {0xAB, 0, 0, 0, 0, 0, 0, 0}},
      {"le 12 at 4", 4, 12, ByteOrder::little_endian, 0xABC, {0xC0, 0xAB, 0, 0, 0, 0, 0, 0}},
      {"le 16 at 48", 48, 16, ByteOrder::little_endian, 0x1234, {0, 0, 0, 0, 0, 0, 0x34, 0x12}},
      {"le 3 at 6 (straddles)", 6, 3, ByteOrder::little_endian, 0x5, {0x40, 0x01, 0, 0, 0, 0, 0, 0}},
      // DBC Motorola: start bit 7 = MSB of byte 0; 16 bits -> bytes 0,1 big-endian.
      {"be 16 at 7", 7, 16, ByteOrder::big_endian, 0x1234, {0x12, 0x34, 0, 0, 0, 0, 0, 0}},
      // start bit 3: MSB at byte 0 bit 3; 12 bits = byte0 bits 3..0 then byte 1.
      {"be 12 at 3", 3, 12, ByteOrder::big_endian, 0xABC, {0x0A, 0xBC, 0, 0, 0, 0, 0, 0}},
      {"be 8 at 63", 63, 8, ByteOrder::big_endian, 0x7E, {0, 0, 0, 0, 0, 0, 0, 0x7E}},
      {"be 4 at 13", 13, 4, ByteOrder::big_endian, 0xF, {0, 0x3C, 0, 0, 0, 0, 0, 0}},
  };
  for (const BitCase& c : cases) {
    std::uint8_t data[8] = {};
    set_bits(data, c.start, c.length, c.order, c.raw);
    EXPECT_EQ(std::vector<std::uint8_t>(data, data + 8), c.bytes) << c.name;
    EXPECT_EQ(get_bits(c.bytes.data(), c.start, c.length, c.order), c.raw) << c.name;
    // Neighbouring bits are preserved by set_bits.
    std::uint8_t ones[8];
    for (auto& b : ones) b = 0xFF;
    set_bits(ones, c.start, c.length, c.order, c.raw);
    EXPECT_EQ(get_bits(ones, c.start, c.length, c.order), c.raw) << c.name;
    int zeros = 0;
    for (std::uint8_t b : ones)
      for (int i = 0; i < 8; ++i) zeros += !((b >> i) & 1);
    int expected_zeros = 0;
    for (int i = 0; i < c.length; ++i) expected_zeros += !((c.raw >> i) & 1);
    EXPECT_EQ(zeros, expected_zeros) << c.name;
  }
}

TEST(CanLayout, ShippedClassicLayoutKnownFrame) {
  const CanLayout l = load("config/can/classic-4hall.yaml");
  EXPECT_EQ(l.can_id, 0x400u);
  EXPECT_EQ(l.id_mask(), 0x700u);
  // Hall codes 0x123, 0x456, 0x789, 0xABC; accel raw -2 (-0.01 m/s^2); frame counter 5.
  const RawSample s = sample(0x123 * kHallLsb, 0x456 * kHallLsb, 0x789 * kHallLsb, 0xABC * kHallLsb, -0.01);
  FrameBytes f;
  EXPECT_EQ(encode(l, &s, 5, 0.0, f), 0);
  EXPECT_EQ(f.id, 0x405u);
  EXPECT_EQ(f.length, 8);
  const std::vector<std::uint8_t> expect = {0x23, 0x61, 0x45, 0x89, 0xC7, 0xAB, 0xFE, 0xFF};
  EXPECT_EQ(std::vector<std::uint8_t>(f.data.begin(), f.data.begin() + 8), expect);
  DecodedFrame d;
  ASSERT_EQ(decode(l, f, d), DecodeStatus::ok);
  ASSERT_EQ(d.count, 1);
  EXPECT_TRUE(d.has_sequence);
  EXPECT_EQ(d.sequence, 5u);
  for (int i = 0; i < 4; ++i) EXPECT_DOUBLE_EQ(d.samples[0].hall_v[i], s.hall_v[i]) << i;  // lossless codes
  EXPECT_DOUBLE_EQ(d.samples[0].accel_mps2, -0.01);
  EXPECT_EQ(d.samples[0].hall_valid_mask, 0xFu);
  EXPECT_TRUE(d.samples[0].accel_valid);
  EXPECT_FALSE(d.samples[0].accel_base_valid);
  // The counter wraps into the id's low 8 bits.
  encode(l, &s, 256 + 7, 0.0, f);
  EXPECT_EQ(f.id, 0x407u);
}

TEST(CanLayout, RoundTripBothShippedLayouts) {
  for (const char* file : {"config/can/classic-4hall.yaml", "config/can/fd-4hall-x8.yaml"}) {
    const CanLayout l = load(file);
    RawSample in[kMaxSamplesPerFrame];
    for (int k = 0; k < l.samples_per_frame; ++k)
      in[k] = sample((100 + 37 * k) * kHallLsb, (4095 - 11 * k) * kHallLsb, (2048 + k) * kHallLsb, (7 * k) * kHallLsb,
                     (k - 3) * 12.34);
    FrameBytes f;
    EXPECT_EQ(encode(l, in, 1234, 0.0, f), 0) << file;
    EXPECT_EQ(f.fd, l.fd);
    DecodedFrame d;
    ASSERT_EQ(decode(l, f, d), DecodeStatus::ok) << file;
    ASSERT_EQ(d.count, l.samples_per_frame);
    EXPECT_EQ(d.sequence, 1234u % l.sequence_wrap());
    for (int k = 0; k < l.samples_per_frame; ++k) {
      for (int i = 0; i < 4; ++i) EXPECT_DOUBLE_EQ(d.samples[k].hall_v[i], in[k].hall_v[i]) << file << " k=" << k;
      EXPECT_NEAR(d.samples[k].accel_mps2, in[k].accel_mps2, l.accel.scale / 2 + 1e-12) << file << " k=" << k;
    }
  }
}

TEST(CanLayout, BigEndianSignedBatchedLayout) {
  // A Motorola layout, 2 samples per frame: accel big-endian signed 16 bit with offset.
  CanLayout l;
  l.name = "be";
  l.can_id = 0x18FF0010;
  l.extended_id = true;
  l.frame_length = 8;
  l.samples_per_frame = 2;
  l.sample_stride_bits = 32;
  l.hall_count = 1;
  l.hall[0] = sig(7, 12, ByteOrder::big_endian, false, 0.001);   // byte 0 + high nibble of byte 1
  l.accel = sig(11, 12, ByteOrder::big_endian, true, 0.1, 1.0);  // low nibble of byte 1 + byte 2
  l.sequence = sig(31, 8, ByteOrder::big_endian);               // byte 3 (shared: per frame)
  // sample 1's copies sit at bytes 4..6; byte 7 is spare. Sequence in byte 3 overlaps nothing.
  EXPECT_EQ(check_layout(l).message, "");
  RawSample in[2] = {sample(1.0, 0, 0, 0, -1.0), sample(4.095, 0, 0, 0, 205.7)};
  in[0].hall_count = in[1].hall_count = 1;
  FrameBytes f;
  EXPECT_EQ(encode(l, in, 0x42, 0.0, f), 0);
  EXPECT_TRUE(f.extended);
  // hall 1000 = 0x3E8 -> 3E 8.; accel (-1 - 1)/0.1 = -20 = 0xFEC -> .F EC; sample 1: FFF, 7FF
  const std::vector<std::uint8_t> expect = {0x3E, 0x8F, 0xEC, 0x42, 0xFF, 0xF7, 0xFF, 0x00};
  EXPECT_EQ(std::vector<std::uint8_t>(f.data.begin(), f.data.begin() + 8), expect);
  DecodedFrame d;
  ASSERT_EQ(decode(l, f, d), DecodeStatus::ok);
  EXPECT_EQ(d.sequence, 0x42u);
  EXPECT_DOUBLE_EQ(d.samples[0].hall_v[0], 1.0);
  EXPECT_NEAR(d.samples[0].accel_mps2, -1.0, 1e-12);  // sign extension of 0xFEC
  EXPECT_NEAR(d.samples[1].hall_v[0], 4.095, 1e-12);
  EXPECT_NEAR(d.samples[1].accel_mps2, 205.7, 1e-9);  // (205.7-1)/0.1 = 2047 = max
  EXPECT_EQ(decode(l, 0x18FF0010, false, false, f.data.data(), 8, d), DecodeStatus::wrong_id);  // standard id
}

TEST(CanLayout, TemperatureRoundTrip) {
  // CAN FD, 2 samples per frame, a per-frame temperature (12 bit signed, 1/16 K) after
  // the counter, as a layout file describes it.
  const std::string text =
      "layout: fd-temp\n"
      "can_id: 0x120\n"
      "fd: true\n"
      "frame_length: 12\n"
      "samples_per_frame: 2\n"
      "sample_stride_bits: 28\n"
      "sample_rate_hz: 4000\n"
      "hall_count: 1\n"
      "signals:\n"
      "  hall_0: {start_bit: 0, length: 12, scale: 0.0012210012210012210}\n"
      "  accel: {start_bit: 12, length: 16, signed: true, scale: 0.005}\n"
      "  sequence: {start_bit: 56, length: 8}\n"
      "  temperature: {start_bit: 64, length: 12, signed: true, scale: 0.0625}\n";
  CanLayout l;
  std::vector<ve::config::ConfigError> errors;
  ASSERT_TRUE(load_can_layout_text("t.yaml", text, l, errors)) << ve::config::to_string(errors);
  ASSERT_TRUE(l.temperature.present);
  EXPECT_EQ(l.temperature.start_bit, 64);
  RawSample in[2] = {sample(1.0, 0, 0, 0, 2.0), sample(2.0, 0, 0, 0, -3.0)};
  in[0].hall_count = in[1].hall_count = 1;
  in[0].temperature_c = 37.3125;  // the frame carries sample 0's
  in[0].temperature_valid = in[1].temperature_valid = true;
  in[1].temperature_c = 99.0;
  FrameBytes f;
  EXPECT_EQ(encode(l, in, 7, 0.0, f), 0);
  EXPECT_EQ(f.data[8] | (f.data[9] & 0x0F) << 8, 597);  // 37.3125 / 0.0625
  DecodedFrame d;
  ASSERT_EQ(decode(l, f, d), DecodeStatus::ok);
  ASSERT_EQ(d.count, 2);
  for (int k = 0; k < 2; ++k) {
    EXPECT_TRUE(d.samples[k].temperature_valid) << k;
    EXPECT_EQ(d.samples[k].temperature_c, 37.3125) << k;
  }
  // Below freezing (sign extension), and beyond the signal's range (saturation).
  in[0].temperature_c = -12.5;
  EXPECT_EQ(encode(l, in, 8, 0.0, f), 0);
  ASSERT_EQ(decode(l, f, d), DecodeStatus::ok);
  EXPECT_EQ(d.samples[1].temperature_c, -12.5);
  in[0].temperature_c = 200.0;
  EXPECT_EQ(encode(l, in, 9, 0.0, f), 1);
  ASSERT_EQ(decode(l, f, d), DecodeStatus::ok);
  EXPECT_EQ(d.samples[0].temperature_c, 2047 * 0.0625);

  // Checked like every signal: it may not overlap another one.
  CanLayout bad = l;
  bad.temperature.start_bit = 50;
  EXPECT_EQ(check_layout(bad).where, "signals.temperature");
  // The shipped layouts carry none: their samples have no temperature.
  for (const char* file : {"config/can/classic-4hall.yaml", "config/can/fd-4hall-x8.yaml"}) {
    const CanLayout shipped = load(file);
    EXPECT_FALSE(shipped.temperature.present) << file;
    RawSample batch[kMaxSamplesPerFrame];
    for (int k = 0; k < shipped.samples_per_frame; ++k) {
      batch[k] = sample(1.0, 1.0, 1.0, 1.0, 0.0);
      batch[k].temperature_c = 30.0;
      batch[k].temperature_valid = true;
    }
    ASSERT_EQ(encode(shipped, batch, 1, 0.0, f), 0) << file;
    ASSERT_EQ(decode(shipped, f, d), DecodeStatus::ok) << file;
    EXPECT_FALSE(d.samples[0].temperature_valid) << file;
  }
}

TEST(CanLayout, SignExtensionAndSaturation) {
  CanLayout l;
  l.can_id = 0x10;
  l.frame_length = 4;
  l.hall_count = 1;
  l.hall[0] = sig(0, 8, ByteOrder::little_endian, false, 0.02);  // 0 .. 5.1 V
  l.accel = sig(8, 12, ByteOrder::little_endian, true, 0.1);     // -204.8 .. 204.7
  l.accel_base = sig(20, 12, ByteOrder::little_endian, true, 1.0);
  ASSERT_EQ(check_layout(l).message, "");
  struct Case {
    double hall, accel, base;
    double hall_out, accel_out, base_out;
    int clamped;
  } cases[] = {
      {1.0, -0.1, -1, 1.0, -0.1, -1, 0},
      {-1.0, -300.0, 5000, 0.0, -204.8, 2047, 3},       // below / above every range
      {9.9, 300.0, -5000, 5.1, 204.7, -2048, 3},
      {std::nan(""), 0.0, 0, 0.0, 0.0, 0, 1},           // NaN -> minimum
      {5.1, -204.8, -2048, 5.1, -204.8, -2048, 0},      // exactly the limits
  };
  for (const Case& c : cases) {
    RawSample s = sample(c.hall, 0, 0, 0, c.accel);
    s.hall_count = 1;
    s.accel_base_mps2 = c.base;
    FrameBytes f;
    EXPECT_EQ(encode(l, &s, 0, 0.0, f), c.clamped) << c.hall << " " << c.accel;
    DecodedFrame d;
    ASSERT_EQ(decode(l, f, d), DecodeStatus::ok);
    EXPECT_NEAR(d.samples[0].hall_v[0], c.hall_out, 1e-12);
    EXPECT_NEAR(d.samples[0].accel_mps2, c.accel_out, 1e-9);
    EXPECT_NEAR(d.samples[0].accel_base_mps2, c.base_out, 1e-9);
    EXPECT_TRUE(d.samples[0].accel_base_valid);
  }
  // Raw all-ones in a signed 12-bit field is -1.
  const std::uint8_t ff[4] = {0, 0xFF, 0x0F, 0};
  DecodedFrame d;
  ASSERT_EQ(decode(l, 0x10, false, false, ff, 4, d), DecodeStatus::ok);
  EXPECT_NEAR(d.samples[0].accel_mps2, -0.1, 1e-12);
}

TEST(CanLayout, RejectsWrongIdLengthAndFormat) {
  const CanLayout l = load("config/can/classic-4hall.yaml");
  std::uint8_t data[64] = {};
  DecodedFrame d;
  EXPECT_EQ(decode(l, 0x4FF, false, false, data, 8, d), DecodeStatus::ok);
  EXPECT_EQ(decode(l, 0x500, false, false, data, 8, d), DecodeStatus::wrong_id);
  EXPECT_EQ(decode(l, 0x3FF, false, false, data, 8, d), DecodeStatus::wrong_id);
  EXPECT_EQ(decode(l, 0x400, true, false, data, 8, d), DecodeStatus::wrong_id);  // extended 0x400
  EXPECT_EQ(decode(l, 0x400, false, false, data, 7, d), DecodeStatus::wrong_length);
  EXPECT_EQ(decode(l, 0x400, false, true, data, 8, d), DecodeStatus::wrong_format);
  const CanLayout fd = load("config/can/fd-4hall-x8.yaml");
  EXPECT_EQ(decode(fd, 0x500, false, true, data, 48, d), DecodeStatus::wrong_length);
  EXPECT_EQ(decode(fd, 0x501, false, true, data, 64, d), DecodeStatus::wrong_id);
  EXPECT_EQ(decode(fd, 0x500, false, true, data, 64, d), DecodeStatus::ok);
  EXPECT_EQ(d.count, 8);
}

TEST(CanLayout, CheckFindsBadLayouts) {
  CanLayout base = load("config/can/classic-4hall.yaml");
  struct Case {
    const char* what;
    void (*mutate)(CanLayout&);
    const char* where;
  } cases[] = {
      {"overlap", [](CanLayout& l) { l.hall[1].start_bit = 6; }, "signals.hall_1"},
      {"outside", [](CanLayout& l) { l.accel.start_bit = 50; }, "signals.accel"},
      {"classic 12 bytes", [](CanLayout& l) { l.frame_length = 12; }, "frame_length"},
      {"fd 13 bytes", [](CanLayout& l) { l.fd = true; l.frame_length = 13; }, "frame_length"},
      {"seq bits in id", [](CanLayout& l) { l.can_id = 0x401; }, "can_id"},
      {"id too big", [](CanLayout& l) { l.can_id = 0x800; }, "can_id"},
      {"missing hall", [](CanLayout& l) { l.hall_count = 5; }, "signals.hall_4"},
      {"no stride", [](CanLayout& l) { l.samples_per_frame = 2; }, "sample_stride_bits"},
      {"zero scale", [](CanLayout& l) { l.hall[2].scale = 0; }, "signals.hall_2.scale"},
  };
  for (const Case& c : cases) {
    CanLayout l = base;
    c.mutate(l);
    const LayoutProblem p = check_layout(l);
    EXPECT_EQ(p.where, c.where) << c.what << ": " << p.message;
    EXPECT_FALSE(p.message.empty()) << c.what;
  }
}

TEST(CanLayout, CheckFindsEveryProblemInOneRun) {
  CanLayout l;
  l.frame_length = 8;
  l.hall_count = 2;
  for (int i = 0; i < 2; ++i) {
    l.hall[static_cast<std::size_t>(i)].present = true;
    l.hall[static_cast<std::size_t>(i)].length = 12;
  }
  l.hall[0].start_bit = 0;
  l.hall[1].start_bit = 6;  // overlaps hall_0
  l.accel.present = true;
  l.accel.length = 16;
  l.accel.start_bit = 60;   // runs out of the 8-byte frame
  l.can_id = 0x900;         // beyond 11 bits
  const std::vector<LayoutProblem> all = check_layout_all(l);
  ASSERT_EQ(all.size(), 3u);
  EXPECT_EQ(all[0].where, "can_id");
  EXPECT_EQ(all[1].where, "signals.hall_1");
  EXPECT_EQ(all[2].where, "signals.accel");
  EXPECT_EQ(check_layout(l).where, "can_id");  // the first one

  // A wrong frame is reported alone: placing signals in it would only repeat it.
  l.frame_length = 12;
  const std::vector<LayoutProblem> frame = check_layout_all(l);
  ASSERT_EQ(frame.size(), 2u);
  EXPECT_EQ(frame[1].where, "frame_length");
}

TEST(CanLayoutFile, ErrorsCarryFileLineColumn) {
  const std::string text =
      "can_id: 0x400\n"
      "frame_length: 8\n"
      "sample_rate_hz: 4000\n"
      "hall_count: 1\n"
      "signals:\n"
      "  hall_0: {start_bit: 0, length: 12}\n"
      "  accel: {start_bit: 8, length: 16, signed: true, byte_order: sideways, scael: 2}\n";
  CanLayout l;
  std::vector<ve::config::ConfigError> errors;
  EXPECT_FALSE(load_can_layout_text("t.yaml", text, l, errors));
  const std::string all = ve::config::to_string(errors);
  EXPECT_NE(all.find("t.yaml:7:"), std::string::npos) << all;
  EXPECT_NE(all.find("'sideways' is not one of"), std::string::npos) << all;
  EXPECT_NE(all.find("did you mean 'scale'"), std::string::npos) << all;

  // Structural problems point at the signal.
  const std::string overlap =
      "can_id: 0x400\nframe_length: 8\nsample_rate_hz: 4000\nhall_count: 1\nsignals:\n"
      "  hall_0: {start_bit: 0, length: 12}\n"
      "  accel: {start_bit: 8, length: 16, signed: true}\n";
  errors.clear();
  EXPECT_FALSE(load_can_layout_text("o.yaml", overlap, l, errors));
  ASSERT_EQ(errors.size(), 1u) << ve::config::to_string(errors);
  EXPECT_EQ(errors[0].line, 7);
  EXPECT_NE(errors[0].message.find("overlaps"), std::string::npos);

  errors.clear();
  EXPECT_FALSE(load_can_layout_text("i.yaml", "can_id: 0xZZ\nframe_length: 8\nsample_rate_hz: 1\nhall_count: 1\n"
                                              "signals: {hall_0: {start_bit: 0, length: 8}, accel: {start_bit: 8, length: 8}}\n",
                                    l, errors));
  ASSERT_FALSE(errors.empty());
  EXPECT_EQ(errors[0].line, 1);
  EXPECT_EQ(errors[0].column, 9);
}

TEST(SocketCanSource, NoCanKernelIsReportedClearly) {
  SocketCanOptions opt;
  opt.interface = "vcan0";
  opt.layout = load("config/can/classic-4hall.yaml");
  opt.timeout_ms = 5;
  SocketCanSource src(opt);
  RawSample s;
  if (src.ok()) {
    // A kernel with CAN and a vcan0 (e.g. inside the test VM): a silent bus times out.
    EXPECT_EQ(src.read(s), ve::drivers::ReadStatus::timeout);
    return;
  }
  const std::string e = src.last_error();
  EXPECT_FALSE(e.empty());
  EXPECT_EQ(src.read(s), ve::drivers::ReadStatus::error);
  // Either no CAN in the kernel (this host) or no such interface.
  EXPECT_TRUE(e.find("no SocketCAN") != std::string::npos || e.find("vcan0") != std::string::npos) << e;
}

TEST(SocketCanSource, InvalidLayoutIsAnError) {
  SocketCanOptions opt;
  opt.interface = "vcan0";
  opt.layout = load("config/can/classic-4hall.yaml");
  opt.layout.frame_length = 9;
  SocketCanSource src(opt);
  EXPECT_FALSE(src.ok());
  EXPECT_NE(src.last_error().find("frame_length"), std::string::npos) << src.last_error();
}
