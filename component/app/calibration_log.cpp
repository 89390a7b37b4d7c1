#include "calibration_log.hpp"

#include "replay/replay_source.hpp"
#include "signals.hpp"

namespace ve::app {

bool read_calibration_log(const std::string& path, int hall_count, std::vector<core::ReferenceSegment>& segments,
                          std::string& error) {
  bool has_reference = false;
  if (!read_calibration_log_any(path, hall_count, segments, has_reference, error)) return false;
  if (!has_reference) {
    segments.clear();
    error = path + ": no ref_position_m column: calibration with a reference needs the ruler's position per sample";
    return false;
  }
  return true;
}

namespace {
/// The most rows a calibration log may have: they are all held in memory (about
/// 150 bytes each, 1.2 GB at most); 8.4 million rows are 35 minutes at 4 kHz.
constexpr std::size_t kMaxCalibrationRows = std::size_t{1} << 23;
}  // namespace

bool read_calibration_log_any(const std::string& path, int hall_count, std::vector<core::ReferenceSegment>& segments,
                              bool& has_reference, std::string& error) {
  replay::ReplaySource log(path, false);
  if (!log.ok()) {
    error = log.last_error();
    return false;
  }
  has_reference = log.meta().has_reference;
  if (log.meta().hall_count != hall_count) {
    error = path + ": the log has " + std::to_string(log.meta().hall_count) + " Hall columns, the motor " +
            std::to_string(hall_count);
    return false;
  }
  segments.clear();
  core::RawSample s;
  std::int64_t last_t = 0;
  std::int64_t period_ns = 0;
  bool open = false;
  drivers::ReadStatus st;
  std::size_t rows = 0;
  while ((st = log.read(s)) == drivers::ReadStatus::ok) {
    if (++rows > kMaxCalibrationRows) {
      segments.clear();
      error = path + ": more than " + std::to_string(kMaxCalibrationRows) +
              " rows: too long for a calibration log (record the calibration motion alone)";
      return false;
    }
    if ((rows & 4095) == 0 && termination_requested()) {
      segments.clear();
      error = path + ": reading interrupted by a signal";
      return false;
    }
    double x = 0.0;
    if (has_reference && !log.reference_position(x)) {
      open = false;
      continue;
    }
    // A new segment when time jumps by more than one and a half periods.
    if (open && period_ns > 0 && s.t_ns - last_t > period_ns * 3 / 2) open = false;
    if (open && period_ns == 0) period_ns = s.t_ns - last_t;
    if (!open) {
      segments.emplace_back();
      open = true;
    }
    segments.back().samples.push_back(s);
    segments.back().reference_m.push_back(x);
    last_t = s.t_ns;
  }
  if (st == drivers::ReadStatus::error) {
    error = log.last_error();
    return false;
  }
  return true;
}

}  // namespace ve::app
