#include "replay/replay_source.hpp"

#include <algorithm>

#include "pacing.hpp"

namespace ve::replay {

namespace {

}  // namespace

ReplaySource::ReplaySource(const std::string& path, bool realtime) : path_(path), realtime_(realtime) {
  ok_ = reader_.open(path);
  if (!ok_) {
    const auto& errors = reader_.errors();
    error_ = errors.empty() ? "replay: cannot read " + path : errors.front().to_string();
    if (reader_.error_count() > 1) error_ += " (and " + std::to_string(reader_.error_count() - 1) + " more)";
  }
}

bool ReplaySource::wait_until_due(std::int64_t t_ns) {
  if (rows_read_.load(std::memory_order_relaxed) == 0) {
    clock_start_ns_ = drivers::monotonic_ns();
    t0_ns_ = t_ns;
    return !stop_.load(std::memory_order_relaxed);
  }
  return drivers::sleep_until(clock_start_ns_ + (t_ns - t0_ns_), stop_);
}

drivers::ReadStatus ReplaySource::read(core::RawSample& out) {
  if (!ok_ || failed_) return drivers::ReadStatus::error;
  if (stop_.load(std::memory_order_relaxed)) return drivers::ReadStatus::stopped;
  RawLogRow next;
  switch (reader_.next(next)) {
    case RawLogReader::Next::end:
      return drivers::ReadStatus::end_of_stream;
    case RawLogReader::Next::error:
      failed_ = true;
      error_ = reader_.last_error().to_string();
      return drivers::ReadStatus::error;
    case RawLogReader::Next::row:
      break;
  }
  if (realtime_ && !wait_until_due(next.sample.t_ns)) return drivers::ReadStatus::stopped;
  row_ = next;
  out = row_.sample;
  rows_read_.fetch_add(1, std::memory_order_relaxed);
  return drivers::ReadStatus::ok;
}

const core::Truth* ReplaySource::truth() const {
  return rows_read_.load(std::memory_order_relaxed) > 0 && row_.has_truth ? &row_.truth : nullptr;
}

bool ReplaySource::reference_position(double& position_m) const {
  if (rows_read_.load(std::memory_order_relaxed) == 0 || !row_.has_reference) return false;
  position_m = row_.reference_position_m;
  return true;
}

std::string ReplaySource::describe() const {
  return "replay(" + path_ + ", " + std::to_string(rows_read_.load(std::memory_order_relaxed)) + " rows read)";
}

}  // namespace ve::replay
