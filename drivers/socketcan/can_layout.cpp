#include "socketcan/can_layout.hpp"

#include <algorithm>
#include <cmath>

namespace ve::socketcan {

namespace {

/// Big-endian: DBC sawtooth start bit (MSB) <-> MSB-first linear position.
int sawtooth_to_linear(int s) { return (s / 8) * 8 + (7 - s % 8); }
int linear_to_sawtooth(int l) { return (l / 8) * 8 + (7 - l % 8); }

/// Start bit of sample k's copy of a per-sample signal.
int shifted_start(const SignalSpec& s, int shift_bits) {
  if (shift_bits == 0) return s.start_bit;
  if (s.order == ByteOrder::little_endian) return s.start_bit + shift_bits;
  return linear_to_sawtooth(sawtooth_to_linear(s.start_bit) + shift_bits);
}

/// Marks the frame bits (as little-endian bit numbers) a signal occupies; false when
/// a bit lies outside [0, frame_bits) or was already taken.
bool occupy(std::array<std::uint64_t, 8>& used, const SignalSpec& s, int start, int frame_bits, bool& outside) {
  outside = false;
  for (int i = 0; i < s.length; ++i) {
    int b;
    if (s.order == ByteOrder::little_endian) {
      b = start + i;
    } else {
      const int l = sawtooth_to_linear(start) + i;
      b = (l / 8) * 8 + (7 - l % 8);
    }
    if (b < 0 || b >= frame_bits) {
      outside = true;
      return false;
    }
    std::uint64_t& w = used[static_cast<std::size_t>(b / 64)];
    const std::uint64_t m = std::uint64_t{1} << (b % 64);
    if (w & m) return false;
    w |= m;
  }
  return true;
}

std::int64_t sign_extend(std::uint64_t raw, int length) {
  const std::uint64_t sign = std::uint64_t{1} << (length - 1);
  return static_cast<std::int64_t>((raw ^ sign)) - static_cast<std::int64_t>(sign);
}

double to_physical(const SignalSpec& s, std::uint64_t raw) {
  const double r = s.is_signed ? static_cast<double>(sign_extend(raw, s.length)) : static_cast<double>(raw);
  return r * s.scale + s.offset;
}

/// Physical -> raw bits, clamped; `clamped` set when the value did not fit.
std::uint64_t to_raw(const SignalSpec& s, double physical, bool& clamped) {
  double r = std::round((physical - s.offset) / s.scale);
  const double lo = static_cast<double>(s.raw_min()), hi = static_cast<double>(s.raw_max());
  clamped = false;
  if (!(r >= lo)) {  // also NaN
    r = lo;
    clamped = true;
  } else if (r > hi) {
    r = hi;
    clamped = true;
  }
  const std::int64_t v = static_cast<std::int64_t>(r);
  const std::uint64_t mask = s.length >= 64 ? ~std::uint64_t{0} : (std::uint64_t{1} << s.length) - 1;
  return static_cast<std::uint64_t>(v) & mask;
}

}  // namespace

std::uint32_t CanLayout::id_mask() const {
  const std::uint32_t all = extended_id ? 0x1FFFFFFFu : 0x7FFu;
  if (!sequence.present || !sequence.in_can_id) return all;
  const std::uint32_t seq_bits = ((sequence.length >= 32 ? 0xFFFFFFFFu : ((1u << sequence.length) - 1u)))
                                 << sequence.start_bit;
  return all & ~seq_bits;
}

std::uint64_t CanLayout::sequence_wrap() const {
  return sequence.present ? (std::uint64_t{1} << sequence.length) : 0;
}

std::int64_t CanLayout::sample_period_ns() const {
  return sample_rate_hz > 0.0 ? static_cast<std::int64_t>(std::llround(1e9 / sample_rate_hz)) : 0;
}

bool valid_fd_length(int n) {
  return (n >= 0 && n <= 8) || n == 12 || n == 16 || n == 20 || n == 24 || n == 32 || n == 48 || n == 64;
}

const char* to_string(DecodeStatus s) {
  switch (s) {
    case DecodeStatus::ok: return "ok";
    case DecodeStatus::wrong_id: return "wrong id";
    case DecodeStatus::wrong_length: return "wrong length";
    case DecodeStatus::wrong_format: return "wrong format (classic/FD)";
  }
  return "?";
}

std::vector<LayoutProblem> check_layout_all(const CanLayout& l) {
  std::vector<LayoutProblem> problems;
  auto problem = [&problems](std::string where, std::string msg) {
    problems.push_back(LayoutProblem{std::move(where), std::move(msg)});
  };
  const std::uint32_t id_limit = l.extended_id ? 0x1FFFFFFFu : 0x7FFu;
  if (l.can_id > id_limit)
    problem("can_id", std::string("does not fit a ") + (l.extended_id ? "29" : "11") + "-bit identifier");
  if (l.fd) {
    if (!valid_fd_length(l.frame_length))
      problem("frame_length", "a CAN FD frame carries 0..8, 12, 16, 20, 24, 32, 48 or 64 bytes, got " +
                                  std::to_string(l.frame_length));
  } else if (l.frame_length < 0 || l.frame_length > 8) {
    problem("frame_length", "a classic CAN frame carries 0..8 bytes, got " + std::to_string(l.frame_length) +
                                " (set fd: true for longer frames)");
  }
  if (l.samples_per_frame < 1 || l.samples_per_frame > kMaxSamplesPerFrame)
    problem("samples_per_frame", "must be 1.." + std::to_string(kMaxSamplesPerFrame));
  if (l.samples_per_frame > 1 && l.sample_stride_bits <= 0)
    problem("sample_stride_bits", "must be > 0 when samples_per_frame > 1");
  if (!(l.sample_rate_hz > 0.0)) problem("sample_rate_hz", "must be > 0");
  if (l.hall_count < 1 || l.hall_count > core::kMaxHalls)
    problem("hall_count", "must be 1.." + std::to_string(core::kMaxHalls));
  if (!l.accel.present) problem("signals.accel", "the accelerometer signal is required");
  // Where the signals lie depends on the frame: placing them in a wrong one would
  // only repeat its problem.
  for (const auto& p : problems)
    if (p.where == "frame_length" || p.where == "samples_per_frame" || p.where == "sample_stride_bits" ||
        p.where == "hall_count")
      return problems;

  auto check_signal = [&](const SignalSpec& s, const std::string& where) -> LayoutProblem {
    if (!s.present) return {};
    if (s.length < 1 || s.length > kMaxSignalBits)
      return LayoutProblem{where + ".length", "must be 1.." + std::to_string(kMaxSignalBits)};
    if (s.start_bit < 0) return LayoutProblem{where + ".start_bit", "must be >= 0"};
    if (!(s.scale != 0.0) || !std::isfinite(s.scale)) return LayoutProblem{where + ".scale", "must be non-zero"};
    return {};
  };
  std::array<std::uint64_t, 8> used{};
  const int frame_bits = l.frame_length * 8;
  // Each signal's first problem; the others are still placed.
  auto place = [&](const SignalSpec& s, const std::string& where, int samples) {
    if (!s.present) return;
    LayoutProblem p = check_signal(s, where);
    if (!p.message.empty()) {
      problems.push_back(std::move(p));
      return;
    }
    for (int k = 0; k < samples; ++k) {
      bool outside = false;
      if (!occupy(used, s, shifted_start(s, k * l.sample_stride_bits), frame_bits, outside)) {
        const std::string which = samples > 1 ? " (copy for sample " + std::to_string(k) + ")" : std::string();
        problem(where, outside ? "bits lie outside the " + std::to_string(l.frame_length) + "-byte frame" + which
                               : "overlaps another signal" + which);
        return;
      }
    }
  };
  for (int i = 0; i < l.hall_count; ++i) {
    const std::string where = "signals.hall_" + std::to_string(i);
    if (!l.hall[static_cast<std::size_t>(i)].present) {
      problem(where, "missing (hall_count is " + std::to_string(l.hall_count) + ")");
      continue;
    }
    place(l.hall[static_cast<std::size_t>(i)], where, l.samples_per_frame);
  }
  for (int i = l.hall_count; i < core::kMaxHalls; ++i)
    if (l.hall[static_cast<std::size_t>(i)].present)
      problem("signals.hall_" + std::to_string(i), "beyond hall_count " + std::to_string(l.hall_count));
  place(l.accel, "signals.accel", l.samples_per_frame);
  place(l.accel_base, "signals.accel_base", l.samples_per_frame);
  if (l.sequence.present) {
    if (l.sequence.is_signed || l.sequence.scale != 1.0 || l.sequence.offset != 0.0) {
      problem("signals.sequence", "a sequence counter is unsigned with scale 1 and offset 0");
    } else if (l.sequence.in_can_id) {
      const LayoutProblem p = check_signal(l.sequence, "signals.sequence");
      const int id_bits = l.extended_id ? 29 : 11;
      if (!p.message.empty())
        problems.push_back(p);
      else if (l.sequence.start_bit + l.sequence.length > id_bits)
        problem("signals.sequence", "bits lie outside the " + std::to_string(id_bits) + "-bit identifier");
      else if (l.can_id <= id_limit && (l.can_id & ~l.id_mask()) != 0)
        problem("can_id", "has bits set where the sequence counter goes (in_can_id)");
    } else {
      place(l.sequence, "signals.sequence", 1);
    }
  }
  place(l.node_timestamp, "signals.node_timestamp", 1);
  place(l.temperature, "signals.temperature", 1);
  return problems;
}

LayoutProblem check_layout(const CanLayout& l) {
  std::vector<LayoutProblem> all = check_layout_all(l);
  return all.empty() ? LayoutProblem{} : std::move(all.front());
}

namespace {

/// Walks a signal's bits one byte at a time: f(byte, shift, n, at) for each byte
/// it touches, the n bits at `shift` (from the byte's LSB) of data[byte] being the
/// value's bits [at, at + n). Little endian: the value's LSB first, from start_bit
/// up; big endian (start_bit in the sawtooth numbering): its MSB first, from the
/// first byte's MSB down and on into the next bytes.
template <class F>
void for_each_byte_of(int start_bit, int length, ByteOrder order, F&& f) {
  const bool little = order == ByteOrder::little_endian;
  int pos = little ? start_bit : sawtooth_to_linear(start_bit);
  for (int done = 0; done < length;) {
    const int off = pos & 7;  // little endian: from the byte's LSB; big endian: from its MSB
    const int n = std::min(8 - off, length - done);
    if (little)
      f(pos >> 3, off, n, done);
    else
      f(pos >> 3, 8 - off - n, n, length - done - n);
    done += n;
    pos += n;
  }
}

}  // namespace

std::uint64_t get_bits(const std::uint8_t* data, int start_bit, int length, ByteOrder order) {
  std::uint64_t raw = 0;
  for_each_byte_of(start_bit, length, order, [&](int byte, int shift, int n, int at) {
    const std::uint64_t chunk = (static_cast<std::uint64_t>(data[byte]) >> shift) & ((1u << n) - 1u);
    raw |= chunk << at;
  });
  return raw;
}

void set_bits(std::uint8_t* data, int start_bit, int length, ByteOrder order, std::uint64_t raw) {
  for_each_byte_of(start_bit, length, order, [&](int byte, int shift, int n, int at) {
    const unsigned mask = ((1u << n) - 1u) << shift;
    const unsigned v = static_cast<unsigned>((raw >> at) & ((1u << n) - 1u)) << shift;
    std::uint8_t& b = data[byte];
    b = static_cast<std::uint8_t>((b & ~mask) | v);
  });
}

bool matches(const CanLayout& layout, std::uint32_t id, bool extended) {
  return extended == layout.extended_id && (id & layout.id_mask()) == layout.can_id;
}

DecodeStatus decode(const CanLayout& l, std::uint32_t id, bool extended, bool fd, const std::uint8_t* data,
                    int length, DecodedFrame& out) {
  if (!matches(l, id, extended)) return DecodeStatus::wrong_id;
  if (fd != l.fd) return DecodeStatus::wrong_format;
  if (length != l.frame_length) return DecodeStatus::wrong_length;
  out.count = l.samples_per_frame;
  out.has_sequence = l.sequence.present;
  if (l.sequence.present) {
    out.sequence = l.sequence.in_can_id
                       ? (id >> l.sequence.start_bit) & ((std::uint64_t{1} << l.sequence.length) - 1)
                       : get_bits(data, l.sequence.start_bit, l.sequence.length, l.sequence.order);
  }
  out.has_node_time = l.node_timestamp.present;
  if (l.node_timestamp.present)
    out.node_time_us = to_physical(
        l.node_timestamp, get_bits(data, l.node_timestamp.start_bit, l.node_timestamp.length, l.node_timestamp.order));
  const std::uint32_t hall_mask = (1u << l.hall_count) - 1u;
  const bool has_temperature = l.temperature.present;
  const double temperature_c =
      has_temperature
          ? to_physical(l.temperature, get_bits(data, l.temperature.start_bit, l.temperature.length, l.temperature.order))
          : 0.0;
  for (int k = 0; k < l.samples_per_frame; ++k) {
    core::RawSample& s = out.samples[static_cast<std::size_t>(k)];
    const int shift = k * l.sample_stride_bits;
    s.t_ns = 0;
    s.seq = 0;
    s.hall_count = l.hall_count;
    for (int i = 0; i < l.hall_count; ++i) {
      const SignalSpec& h = l.hall[static_cast<std::size_t>(i)];
      s.hall_v[static_cast<std::size_t>(i)] = to_physical(h, get_bits(data, shifted_start(h, shift), h.length, h.order));
    }
    s.hall_valid_mask = hall_mask;
    s.accel_mps2 = to_physical(l.accel, get_bits(data, shifted_start(l.accel, shift), l.accel.length, l.accel.order));
    s.accel_valid = true;
    if (l.accel_base.present) {
      s.accel_base_mps2 = to_physical(
          l.accel_base, get_bits(data, shifted_start(l.accel_base, shift), l.accel_base.length, l.accel_base.order));
      s.accel_base_valid = true;
    } else {
      s.accel_base_mps2 = 0.0;
      s.accel_base_valid = false;
    }
    s.temperature_c = temperature_c;
    s.temperature_valid = has_temperature;
  }
  return DecodeStatus::ok;
}

int encode(const CanLayout& l, const core::RawSample* samples, std::uint64_t sequence, double node_time_us,
           FrameBytes& out) {
  int clamped_count = 0;
  bool clamped = false;
  out.extended = l.extended_id;
  out.fd = l.fd;
  out.length = static_cast<std::uint8_t>(l.frame_length);
  out.data.fill(0);
  out.id = l.can_id;
  std::uint8_t* d = out.data.data();
  if (l.sequence.present) {
    const std::uint64_t raw = sequence & (l.sequence_wrap() - 1);
    if (l.sequence.in_can_id)
      out.id |= static_cast<std::uint32_t>(raw << l.sequence.start_bit);
    else
      set_bits(d, l.sequence.start_bit, l.sequence.length, l.sequence.order, raw);
  }
  if (l.node_timestamp.present) {
    const SignalSpec& t = l.node_timestamp;
    // The node clock wraps: keep the low bits rather than saturating. Taken in floating
    // point (fmod is exact), as the count may be far beyond 64 bits; not finite -> 0.
    const double r = std::round((node_time_us - t.offset) / t.scale);
    const double wrap = std::ldexp(1.0, t.length);
    double low = std::isfinite(r) ? std::fmod(r, wrap) : 0.0;
    if (low < 0.0) low += wrap;
    const std::uint64_t raw = static_cast<std::uint64_t>(low);
    set_bits(d, t.start_bit, t.length, t.order, raw);
  }
  if (l.temperature.present) {
    const SignalSpec& t = l.temperature;
    set_bits(d, t.start_bit, t.length, t.order, to_raw(t, samples[0].temperature_c, clamped));
    clamped_count += clamped;
  }
  for (int k = 0; k < l.samples_per_frame; ++k) {
    const core::RawSample& s = samples[k];
    const int shift = k * l.sample_stride_bits;
    for (int i = 0; i < l.hall_count; ++i) {
      const SignalSpec& h = l.hall[static_cast<std::size_t>(i)];
      set_bits(d, shifted_start(h, shift), h.length, h.order, to_raw(h, s.hall_v[static_cast<std::size_t>(i)], clamped));
      clamped_count += clamped;
    }
    set_bits(d, shifted_start(l.accel, shift), l.accel.length, l.accel.order, to_raw(l.accel, s.accel_mps2, clamped));
    clamped_count += clamped;
    if (l.accel_base.present) {
      set_bits(d, shifted_start(l.accel_base, shift), l.accel_base.length, l.accel_base.order,
               to_raw(l.accel_base, s.accel_base_mps2, clamped));
      clamped_count += clamped;
    }
  }
  return clamped_count;
}

}  // namespace ve::socketcan
