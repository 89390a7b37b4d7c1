// How a sensor node packs its samples into CAN / CAN FD frames, described the way a
// DBC file describes signals, and the (pure, allocation-free) encoder and decoder.
// No sockets here: socketcan_source.cpp and the sensor-node emulator use this.
//
// Bit numbering (DBC conventions):
//  - little_endian (Intel, DBC "@1"): start_bit is the signal's least significant bit;
//    bit b is bit (b % 8) of byte (b / 8); the signal runs towards higher b.
//  - big_endian (Motorola, DBC "@0"): start_bit is the signal's MOST significant bit in
//    the same "sawtooth" numbering (bit 7 of byte 0 is 7, bit 0 of byte 1 is 8); the
//    signal continues to bit 0 of that byte and then on with bit 7 of the next byte.
// physical = raw * scale + offset, raw two's complement when is_signed.
//
// Several samples per frame (CAN FD batching): the per-sample signals (Halls and
// accelerometers) describe sample 0; sample k's copy sits k * sample_stride_bits later
// (in the signal's own bit stream: little-endian bit numbers for little-endian signals,
// MSB-first positions for big-endian ones). Samples are in time order, oldest first.
// The sequence counter, node timestamp and temperature are per frame and refer to
// sample 0 (the decoder gives the frame's temperature to each of its samples).
// The sequence counter may live in the low bits of the CAN id (sequence.in_can_id):
// start_bit/length then number the bits of the identifier.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "core/sample.hpp"

namespace ve::socketcan {

inline constexpr int kMaxFrameBytes = 64;
inline constexpr int kMaxSamplesPerFrame = 32;
inline constexpr int kMaxSignalBits = 32;

enum class ByteOrder : std::uint8_t { little_endian, big_endian };

struct SignalSpec {
  bool present = false;
  int start_bit = 0;
  int length = 0;  ///< 1 .. kMaxSignalBits
  ByteOrder order = ByteOrder::little_endian;
  bool is_signed = false;
  double scale = 1.0;  ///< physical per raw count; non-zero
  double offset = 0.0;
  bool in_can_id = false;  ///< sequence only: the bits are in the CAN identifier

  /// Smallest and largest raw value.
  std::int64_t raw_min() const { return is_signed ? -(std::int64_t{1} << (length - 1)) : 0; }
  std::int64_t raw_max() const {
    return is_signed ? (std::int64_t{1} << (length - 1)) - 1 : (std::int64_t{1} << length) - 1;
  }
};

struct CanLayout {
  std::string name;                 ///< for messages
  std::uint32_t can_id = 0x100;     ///< identifier (sequence bits, if in the id, zero)
  bool extended_id = false;         ///< 29-bit identifier
  bool fd = false;                  ///< CAN FD frames
  int frame_length = 8;             ///< data bytes; classic 0..8, FD 0..8,12,16,20,24,32,48,64
  int samples_per_frame = 1;        ///< 1 .. kMaxSamplesPerFrame
  int sample_stride_bits = 0;       ///< distance between consecutive samples' signals
  double sample_rate_hz = 4000.0;   ///< expected; t_ns follows sequence * 1/rate
  int hall_count = 4;               ///< 1 .. core::kMaxHalls
  std::array<SignalSpec, core::kMaxHalls> hall{};  ///< volts
  SignalSpec accel;                 ///< m/s^2, required
  SignalSpec accel_base;            ///< m/s^2, optional frame accelerometer
  SignalSpec sequence;              ///< counter (scale 1, offset 0), optional but recommended
  SignalSpec node_timestamp;        ///< microseconds of sample 0 on the node's clock, optional
  SignalSpec temperature;           ///< deg C, optional, per frame: RawSample::temperature_c

  /// Identifier bits that select this layout (all but the sequence bits in the id).
  std::uint32_t id_mask() const;
  /// Period of the sequence counter in frames (2^length), 0 without a counter.
  std::uint64_t sequence_wrap() const;
  std::int64_t sample_period_ns() const;
};

/// Everything wrong with a layout, "" when it is usable: lengths, bits outside the
/// frame, overlapping signals, identifier ranges, scale 0. `where` names the field.
struct LayoutProblem {
  std::string where;    ///< e.g. "signals.hall_2", "frame_length"; "" for the whole layout
  std::string message;
};
/// First problem found; where/message empty when the layout is valid.
LayoutProblem check_layout(const CanLayout& layout);
/// Every problem, in the order check_layout() looks for them (one per signal; the
/// signals are not placed in a frame that is itself wrong). Empty when valid.
std::vector<LayoutProblem> check_layout_all(const CanLayout& layout);

/// One CAN / CAN FD frame's identifier and payload.
struct FrameBytes {
  std::uint32_t id = 0;   ///< without the EFF/RTR/ERR flags
  bool extended = false;
  bool fd = false;
  std::uint8_t length = 0;
  std::array<std::uint8_t, kMaxFrameBytes> data{};
};

/// Samples of one frame, decoded; RawSample::seq and t_ns are left 0 (the source
/// sets them from the counter and its time base).
struct DecodedFrame {
  int count = 0;
  bool has_sequence = false;
  std::uint64_t sequence = 0;        ///< raw counter, 0 .. sequence_wrap() - 1
  bool has_node_time = false;
  double node_time_us = 0.0;         ///< physical value, before unwrapping
  std::array<core::RawSample, kMaxSamplesPerFrame> samples;
};

enum class DecodeStatus { ok, wrong_id, wrong_length, wrong_format };
const char* to_string(DecodeStatus s);

/// Does `id` (flags stripped) belong to this layout?
bool matches(const CanLayout& layout, std::uint32_t id, bool extended);

/// Decodes a frame. wrong_id: not this layout's identifier; wrong_length: the payload is
/// not frame_length bytes; wrong_format: classic vs FD mismatch. Allocation-free.
DecodeStatus decode(const CanLayout& layout, std::uint32_t id, bool extended, bool fd, const std::uint8_t* data,
                    int length, DecodedFrame& out);
inline DecodeStatus decode(const CanLayout& layout, const FrameBytes& f, DecodedFrame& out) {
  return decode(layout, f.id, f.extended, f.fd, f.data.data(), f.length, out);
}

/// Encodes samples[0 .. samples_per_frame-1] with frame counter `sequence` (taken modulo
/// the wrap) and node time `node_time_us` of sample 0. Out-of-range values are clamped
/// to the signal's raw range (saturation; NaN goes to the minimum); returns how many
/// signal values were clamped. The node timestamp keeps its low bits (it wraps).
/// hall_valid_mask / accel_valid / temperature_valid are not encoded: the values are
/// sent as given (the temperature is sample 0's).
/// Allocation-free.
int encode(const CanLayout& layout, const core::RawSample* samples, std::uint64_t sequence, double node_time_us,
           FrameBytes& out);

/// Raw bit access (exposed for tests): value of `length` bits at `start_bit` in
/// `order`, and the inverse. `data` must hold the frame; bits outside are never touched.
std::uint64_t get_bits(const std::uint8_t* data, int start_bit, int length, ByteOrder order);
void set_bits(std::uint8_t* data, int start_bit, int length, ByteOrder order, std::uint64_t raw);

/// CAN FD payload lengths: 0..8, 12, 16, 20, 24, 32, 48, 64.
bool valid_fd_length(int n);

}  // namespace ve::socketcan
