// Fuzz target: CAN / CAN FD frames decoded with every shipped layout (config/can/*.yaml).
//
// The input is a stream of frames as the socket hands them over, each
//   4 bytes  can_id, little-endian, with the EFF / RTR / ERR flag bits as the kernel sets them
//   1 byte   bit 0: CAN FD frame (CANFD_MTU) rather than classic (CAN_MTU)
//   1 byte   payload length: anything 0..255, so also lengths no frame can have
//   N bytes  payload, N = min(length, what is left of the input)
// The flags are stripped as the receive path does (error and remote frames never reach
// the decoder), then every layout decodes the frame from a buffer of exactly the given
// length, so any read past the payload is a heap overflow.
//
// Checks beyond "no crash, no sanitizer report":
//  - a frame is accepted only with the layout's id, format and length;
//  - every decoded value is finite and inside the signal's physical range, the counter
//    inside its wrap, the sample count the layout's;
//  - encoding the decoded samples gives back the same identifier, and decoding that
//    frame gives back exactly the same samples, counter and node time.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <string>
#include <vector>

#include "socketcan/can_layout.hpp"
#include "config/can_layout_file.hpp"

namespace {

using namespace ve::socketcan;

// Flag bits of struct can_frame's can_id (linux/can.h), kept here so the target does
// not depend on kernel headers.
constexpr std::uint32_t kEffFlag = 0x80000000u;
constexpr std::uint32_t kRtrFlag = 0x40000000u;
constexpr std::uint32_t kErrFlag = 0x20000000u;
constexpr std::uint32_t kEffMask = 0x1FFFFFFFu;
constexpr std::uint32_t kSffMask = 0x000007FFu;

[[noreturn]] void fail(const char* what, const CanLayout& l) {
  std::fprintf(stderr, "fuzz_can_frame: layout '%s': %s\n", l.name.c_str(), what);
  std::abort();
}

/// The shipped layouts. The source tree is found from this file's path (or
/// VE_SOURCE_DIR); a target that loaded nothing would test nothing, so that aborts.
const std::vector<CanLayout>& shipped_layouts() {
  static const std::vector<CanLayout> layouts = [] {
    namespace fs = std::filesystem;
    const char* env = std::getenv("VE_SOURCE_DIR");
    const fs::path root = env ? fs::path(env) : fs::path(__FILE__).parent_path().parent_path().parent_path();
    const fs::path dir = root / "config" / "can";
    std::vector<fs::path> files;
    std::error_code ec;
    for (const auto& e : fs::directory_iterator(dir, ec))
      if (e.path().extension() == ".yaml") files.push_back(e.path());
    std::sort(files.begin(), files.end());
    std::vector<CanLayout> out;
    for (const auto& f : files) {
      CanLayout l;
      std::vector<ve::config::ConfigError> errors;
      if (!load_can_layout_file(f.string(), l, errors)) {
        std::fprintf(stderr, "fuzz_can_frame: %s\n", ve::config::to_string(errors).c_str());
        std::abort();
      }
      out.push_back(l);
    }
    if (out.empty()) {
      std::fprintf(stderr, "fuzz_can_frame: no layouts in %s (set VE_SOURCE_DIR)\n", dir.string().c_str());
      std::abort();
    }
    return out;
  }();
  return layouts;
}

bool within(const SignalSpec& s, double v) {
  if (!std::isfinite(v)) return false;
  const double a = static_cast<double>(s.raw_min()) * s.scale + s.offset;
  const double b = static_cast<double>(s.raw_max()) * s.scale + s.offset;
  const double lo = std::min(a, b), hi = std::max(a, b);
  const double slack = 1e-9 * std::max(std::abs(lo), std::abs(hi));
  return v >= lo - slack && v <= hi + slack;
}

bool same(const DecodedFrame& a, const DecodedFrame& b) {
  if (a.count != b.count || a.has_sequence != b.has_sequence || a.sequence != b.sequence ||
      a.has_node_time != b.has_node_time || std::memcmp(&a.node_time_us, &b.node_time_us, sizeof(double)) != 0)
    return false;
  for (int k = 0; k < a.count; ++k) {
    const auto& x = a.samples[static_cast<std::size_t>(k)];
    const auto& y = b.samples[static_cast<std::size_t>(k)];
    if (x.hall_count != y.hall_count || x.hall_valid_mask != y.hall_valid_mask || x.accel_valid != y.accel_valid ||
        x.accel_base_valid != y.accel_base_valid || x.hall_v != y.hall_v || x.accel_mps2 != y.accel_mps2 ||
        x.accel_base_mps2 != y.accel_base_mps2)
      return false;
  }
  return true;
}

void check_decoded(const CanLayout& l, std::uint32_t id, bool ext, bool fd, int len, const DecodedFrame& d) {
  if (!matches(l, id, ext) || fd != l.fd || len != l.frame_length) fail("accepted a frame that is not its own", l);
  if (d.count != l.samples_per_frame) fail("sample count differs from samples_per_frame", l);
  if (d.has_sequence != l.sequence.present) fail("has_sequence differs from the layout", l);
  if (d.has_sequence && d.sequence >= l.sequence_wrap()) fail("sequence counter beyond its wrap", l);
  if (d.has_node_time && !within(l.node_timestamp, d.node_time_us)) fail("node time outside its range", l);
  for (int k = 0; k < d.count; ++k) {
    const auto& s = d.samples[static_cast<std::size_t>(k)];
    if (s.hall_count != l.hall_count) fail("hall_count differs from the layout", l);
    for (int i = 0; i < l.hall_count; ++i)
      if (!within(l.hall[static_cast<std::size_t>(i)], s.hall_v[static_cast<std::size_t>(i)]))
        fail("Hall value outside its signal's range", l);
    if (!s.accel_valid || !within(l.accel, s.accel_mps2)) fail("accelerometer value outside its range", l);
    if (s.accel_base_valid != l.accel_base.present) fail("accel_base_valid differs from the layout", l);
    if (s.accel_base_valid && !within(l.accel_base, s.accel_base_mps2)) fail("frame accelerometer outside its range", l);
  }
  // Round trip: what a sensor node would send for these samples decodes to the same.
  FrameBytes again;
  const int clamped = encode(l, d.samples.data(), d.sequence, d.node_time_us, again);
  if (clamped != 0) fail("re-encoding decoded values clamped some", l);
  if (again.id != id || again.extended != ext || again.fd != fd || again.length != len)
    fail("re-encoded frame has another id, format or length", l);
  static DecodedFrame d2;
  if (decode(l, again, d2) != DecodeStatus::ok) fail("re-encoded frame does not decode", l);
  if (!same(d, d2)) fail("decode(encode(decode(frame))) differs from decode(frame)", l);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::vector<CanLayout>& layouts = shipped_layouts();
  static DecodedFrame out;  // large: keep it off the stack, as the source does
  std::size_t pos = 0;
  while (size - pos >= 6) {
    std::uint32_t raw_id = 0;
    std::memcpy(&raw_id, data + pos, 4);  // little-endian hosts only, which is all we build for
    const bool fd = (data[pos + 4] & 1u) != 0;
    const int len = data[pos + 5];
    pos += 6;
    const std::size_t have = std::min<std::size_t>(static_cast<std::size_t>(len), size - pos);
    // Exactly `len` bytes, so a read beyond the frame is caught; missing input bytes are 0.
    std::vector<std::uint8_t> payload(static_cast<std::size_t>(len));
    if (have > 0) std::memcpy(payload.data(), data + pos, have);
    pos += have;
    // As the receive path: error frames and remote frames never reach the decoder.
    if (raw_id & (kErrFlag | kRtrFlag)) continue;
    const bool ext = (raw_id & kEffFlag) != 0;
    const std::uint32_t id = raw_id & (ext ? kEffMask : kSffMask);
    for (const CanLayout& l : layouts) {
      const DecodeStatus st = decode(l, id, ext, fd, payload.data(), len, out);
      if (st == DecodeStatus::ok) {
        check_decoded(l, id, ext, fd, len, out);
      } else if (st == DecodeStatus::wrong_id) {
        if (matches(l, id, ext)) fail("wrong_id for a matching id", l);
      }
      (void)to_string(st);
    }
  }
  return 0;
}
