// The frame layout file (config/can/*.yaml) -> CanLayout, every problem reported as
// FILE:LINE:COL: FIELD: MESSAGE through the config schema layer. Header-only on
// purpose: it is compiled into the config loader (driver section of a machine file)
// and into the sensor-node command (--layout FILE), and keeps ve_drivers free of YAML.
// It lives in the config layer (it reads a file with the config schema), while the
// layout it fills stays the SocketCAN driver's (drivers/socketcan/can_layout.hpp,
// namespace ve::socketcan): config may include drivers, drivers never config.
//
// Schema (see config/can/classic-4hall.yaml for a documented example):
//   layout: NAME                       # optional, for messages
//   can_id: 0x400                      # decimal or 0x hex; sequence bits (in_can_id) zero
//   extended_id: false                 # 29-bit identifier
//   fd: false                          # CAN FD
//   frame_length: 8                    # data bytes
//   samples_per_frame: 1               # samples per frame, oldest first
//   sample_stride_bits: 0              # bits between sample k and k+1 (required when > 1 sample)
//   sample_rate_hz: 4000               # must equal the motor's sample_rate_hz
//   hall_count: 4                      # must equal the motor's hall.count
//   signals:                           # hall_0 .. hall_{N-1}, accel required; the rest optional
//     hall_0: {start_bit: 0, length: 12, byte_order: little_endian, signed: false, scale: 0.0012210012, offset: 0}
//     accel: {...}  accel_base: {...}  node_timestamp: {...}   # node_timestamp scales to microseconds
//     temperature: {...}               # deg C, once per frame (sample 0's), e.g. 12 bit signed x 0.0625
//     sequence: {start_bit: 0, length: 8, in_can_id: true}
#pragma once

#include <cerrno>
#include <cstdlib>
#include <string>
#include <utility>
#include <vector>

#include "config/loader.hpp"
#include "socketcan/can_layout.hpp"

namespace ve::socketcan {

namespace layout_file_detail {

using config::schema::Map;
using config::schema::Value;

/// "0x1A0", "416" -> value; false if neither.
inline bool parse_id(const std::string& s, std::uint32_t& out) {
  if (s.empty()) return false;
  const bool hex = s.size() > 2 && s[0] == '0' && (s[1] == 'x' || s[1] == 'X');
  const char* p = s.c_str() + (hex ? 2 : 0);
  if (*p == '\0') return false;
  char* end = nullptr;
  errno = 0;
  const unsigned long long v = std::strtoull(p, &end, hex ? 16 : 10);
  if (errno != 0 || *end != '\0' || v > 0x1FFFFFFFull || *p == '-' || *p == '+') return false;
  out = static_cast<std::uint32_t>(v);
  return true;
}

struct Reader {
  std::vector<std::pair<std::string, Value>> fields;  // where -> value, for layout problems

  void remember(const std::string& where, Map& m, std::string_view key) { fields.emplace_back(where, m.value(key)); }

  void signal(Map s, SignalSpec& out, const std::string& where, bool is_sequence) {
    out.present = true;
    s.require("start_bit", out.start_bit, config::schema::in_range(0, 511, "(bit number)"));
    s.require("length", out.length, config::schema::in_range(1, kMaxSignalBits, "bits"));
    s.get_enum("byte_order", out.order,
               {{"little_endian", ByteOrder::little_endian},
                {"big_endian", ByteOrder::big_endian},
                {"intel", ByteOrder::little_endian},
                {"motorola", ByteOrder::big_endian}});
    s.get("signed", out.is_signed);
    // Physical units per raw count (V, m/s^2, us, deg C): no sensor needs more than 1e6
    // per count, nor a resolution finer than 1e-12; a scale of 0 would lose the signal.
    s.get("scale", out.scale, [](const double& x) {
      if (x == 0.0) return std::string("must be non-zero: a scale of 0 maps every raw value to the offset");
      const double a = x < 0.0 ? -x : x;
      return a >= 1e-12 && a <= 1e6 ? std::string()
                                    : config::schema::compact_number(x) + " out of range [1e-12, 1e+06] in magnitude "
                                                                          "(physical units per count)";
    });
    s.get("offset", out.offset, config::schema::in_range(-1e9, 1e9, "(physical units)"));
    if (is_sequence)
      s.get("in_can_id", out.in_can_id);
    else
      s.reject("in_can_id", "only the sequence counter can live in the CAN id");
    for (const char* k : {"start_bit", "length", "byte_order", "signed", "scale", "offset", "in_can_id"})
      remember(where + "." + k, s, k);
  }

  void read(Map& root, CanLayout& l) {
    root.get("layout", l.name);
    const Value id = root.required("can_id");
    if (id.present()) {
      std::string s;
      if (id.as(s) && !parse_id(s, l.can_id)) id.error("expected an identifier (decimal or 0x hex, <= 0x1FFFFFFF), got '" + s + "'");
    }
    root.get("extended_id", l.extended_id);
    root.get("fd", l.fd);
    root.require("frame_length", l.frame_length, config::schema::in_range(0, kMaxFrameBytes, "bytes"));
    root.get("samples_per_frame", l.samples_per_frame, config::schema::in_range(1, kMaxSamplesPerFrame, "samples"));
    root.get("sample_stride_bits", l.sample_stride_bits, config::schema::in_range(0, 512, "bits"));
    // The motor file's range: the layout's rate must equal the motor's.
    root.require("sample_rate_hz", l.sample_rate_hz, config::schema::in_range(100.0, 100000.0, "Hz"));
    root.require("hall_count", l.hall_count, config::schema::in_range(1, core::kMaxHalls, "sensors"));
    for (const char* k : {"can_id", "extended_id", "fd", "frame_length", "samples_per_frame", "sample_stride_bits",
                          "sample_rate_hz", "hall_count"})
      remember(k, root, k);
    const Value sv = root.required("signals");
    fields.emplace_back("signals", root.value("signals"));
    Map sig = sv.as_map();
    for (int i = 0; i < core::kMaxHalls; ++i) {
      const std::string key = "hall_" + std::to_string(i);
      if (sig.has(key)) signal(sig.map(key), l.hall[static_cast<std::size_t>(i)], "signals." + key, false);
      else sig.value(key);  // known key, for typo suggestions
      remember("signals." + key, sig, key);
    }
    const std::pair<const char*, SignalSpec*> others[] = {
        {"accel", &l.accel},       {"accel_base", &l.accel_base},         {"sequence", &l.sequence},
        {"node_timestamp", &l.node_timestamp}, {"temperature", &l.temperature}};
    for (const auto& [key, spec] : others) {
      if (sig.has(key)) signal(sig.map(key), *spec, std::string("signals.") + key, spec == &l.sequence);
      else sig.value(key);
      remember(std::string("signals.") + key, sig, key);
    }
    if (errors_before_check_ == errors_->size()) {
      for (const LayoutProblem& p : check_layout_all(l)) at(p.where, root).error(p.message);
    }
  }

  /// The value a problem's `where` names, or the closest enclosing one present.
  const Value& at(const std::string& where, Map& root) {
    const Value* best = nullptr;
    std::size_t best_len = 0;
    for (const auto& [w, v] : fields) {
      if (!v.present()) continue;
      if ((where == w || (where.size() > w.size() && where.compare(0, w.size(), w) == 0 && where[w.size()] == '.')) &&
          w.size() >= best_len) {
        best = &v;
        best_len = w.size();
      }
    }
    if (best) return *best;
    fallback_ = root.value("signals");
    return fallback_;
  }

  std::vector<config::ConfigError>* errors_ = nullptr;
  std::size_t errors_before_check_ = 0;
  Value fallback_;
};

}  // namespace layout_file_detail

/// Parses a layout document's text; `display_name` prefixes the messages. True when
/// the layout is complete and passes check_layout().
inline bool load_can_layout_text(const std::string& display_name, const std::string& text, CanLayout& out,
                                 std::vector<config::ConfigError>& errors) {
  const std::size_t before = errors.size();
  config::schema::Document doc(display_name, errors);
  if (!doc.parse(text)) return false;
  {
    layout_file_detail::Reader r;
    r.errors_ = &errors;
    r.errors_before_check_ = errors.size();
    config::schema::Map root = doc.root();
    if (root.valid()) r.read(root, out);
    r.fields.clear();
  }
  return errors.size() == before;
}

/// Reads and parses a layout file from disk.
inline bool load_can_layout_file(const std::string& path, CanLayout& out, std::vector<config::ConfigError>& errors) {
  std::string text, why;
  if (!config::schema::read_text_file(path, text, why)) {
    errors.push_back({path, 0, 0, "", "cannot read layout file: " + why});
    return false;
  }
  const bool ok = load_can_layout_text(path, text, out, errors);
  config::schema::sort_errors(errors);
  return ok;
}

}  // namespace ve::socketcan
