// Fuzz target: CAN frame layout files (config/can/*.yaml -> CanLayout, file:line:col errors).
// A layout that loads must also be usable: it passes check_layout(), decodes frames of
// its own length, and encodes any sample values (NaN, infinities, huge numbers, any node
// time) into a frame that decodes again.
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <string>
#include <vector>

#include "socketcan/can_layout.hpp"
#include "config/can_layout_file.hpp"

namespace {

using namespace ve::socketcan;

[[noreturn]] void fail(const char* what) {
  std::fprintf(stderr, "fuzz_can_layout: %s\n", what);
  std::abort();
}

void exercise(const CanLayout& l) {
  const LayoutProblem p = check_layout(l);
  if (!p.message.empty()) fail("a layout that loaded fails check_layout()");
  (void)l.id_mask();
  (void)l.sample_period_ns();
  static DecodedFrame out;
  // Frames of the layout's own id and length: all zeros, all ones, a pattern.
  for (int pattern = 0; pattern < 3; ++pattern) {
    std::vector<std::uint8_t> payload(static_cast<std::size_t>(l.frame_length));
    for (std::size_t i = 0; i < payload.size(); ++i)
      payload[i] = pattern == 0 ? 0x00 : pattern == 1 ? 0xFF : static_cast<std::uint8_t>(0xA5 ^ (i * 37));
    const std::uint32_t id = l.can_id | (pattern == 1 ? ~l.id_mask() & (l.extended_id ? 0x1FFFFFFFu : 0x7FFu) : 0u);
    if (decode(l, id, l.extended_id, l.fd, payload.data(), l.frame_length, out) != DecodeStatus::ok)
      fail("a frame of the layout's own id, format and length is refused");
  }
  // Any values encode (clamped) into a frame that decodes.
  constexpr double inf = std::numeric_limits<double>::infinity();
  const double values[] = {0.0, 1.0, -1.0, 2.5, 1e300, -1e300, inf, -inf, std::nan("")};
  const double node_times[] = {0.0, 1e6, -1.0, 4.2e15, 1e300, -1e300, inf, std::nan("")};
  static ve::core::RawSample samples[kMaxSamplesPerFrame];
  FrameBytes f;
  for (std::size_t v = 0; v < sizeof values / sizeof values[0]; ++v) {
    for (int k = 0; k < kMaxSamplesPerFrame; ++k) {
      auto& s = samples[k];
      s.hall_count = l.hall_count;
      for (auto& h : s.hall_v) h = values[(v + static_cast<std::size_t>(k)) % (sizeof values / sizeof values[0])];
      s.accel_mps2 = values[v];
      s.accel_base_mps2 = -values[v];
    }
    const double t = node_times[v % (sizeof node_times / sizeof node_times[0])];
    (void)encode(l, samples, static_cast<std::uint64_t>(v) * 0x9E3779B97F4A7C15ull, t, f);
    if (f.length != l.frame_length || f.fd != l.fd || f.extended != l.extended_id)
      fail("an encoded frame has another format or length than its layout");
    if (decode(l, f, out) != DecodeStatus::ok) fail("an encoded frame does not decode");
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  CanLayout layout;
  std::vector<ve::config::ConfigError> errors;
  const bool ok = load_can_layout_text("layout.yaml", text, layout, errors);
  for (const auto& e : errors) (void)e.to_string();
  if (ok != errors.empty()) fail("load_can_layout_text()'s result disagrees with its error list");
  if (ok) exercise(layout);
  return 0;
}
