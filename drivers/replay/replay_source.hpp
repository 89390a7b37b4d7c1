// Plays back a raw log (raw_log.hpp) as a sensor source: as fast as possible, or
// paced by the log's t_s on CLOCK_MONOTONIC like the simulator.
#pragma once

#include <atomic>
#include <cstdint>
#include <string>
#include <vector>

#include "core/sample.hpp"
#include "replay/raw_log.hpp"
#include "source.hpp"

namespace ve::replay {

class ReplaySource final : public drivers::SensorSource {
 public:
  /// Opens the log and reads its header. Never throws: when the log cannot be
  /// opened or its header is bad, ok() is false, last_error() says why and read()
  /// returns ReadStatus::error.
  ReplaySource(const std::string& path, bool realtime);

  bool ok() const { return ok_; }
  const RawLogMeta& meta() const { return reader_.meta(); }

  /// The next row: t_ns = llround(t_s * 1e9), seq = row index (0-based).
  /// Realtime: the first call returns at once and starts the clock; row n is returned
  /// no earlier than t_n - t_0 later on CLOCK_MONOTONIC (no drift; a late caller
  /// catches up without sleeping). end_of_stream after the last row; error (for this
  /// and every later call) on a malformed row, with last_error() = its LogError text.
  drivers::ReadStatus read(core::RawSample& out) override;
  /// Truth of the row last read, when it has truth cells.
  const core::Truth* truth() const override;
  /// ref_position_m of the row last read, when it has one.
  bool reference_position(double& position_m) const override;
  /// Wakes a sleeping read() within a few ms; every later read() returns stopped.
  void stop() override { stop_.store(true, std::memory_order_relaxed); }
  /// "replay(FILE, N rows read)".
  std::string describe() const override;
  std::string last_error() const override { return error_; }

  /// Unknown columns, a missing version line, repeated metadata keys.
  const std::vector<std::string>& warnings() const { return reader_.warnings(); }
  std::uint64_t rows_read() const { return rows_read_.load(std::memory_order_relaxed); }

 private:
  bool wait_until_due(std::int64_t t_ns);  // false: stopped while waiting

  std::string path_;
  bool realtime_ = false;
  RawLogReader reader_;
  bool ok_ = false;
  bool failed_ = false;  // a row was malformed: read() returns error from now on
  std::string error_;
  RawLogRow row_;
  std::atomic<std::uint64_t> rows_read_{0};
  std::atomic<bool> stop_{false};
  std::int64_t clock_start_ns_ = 0;  // CLOCK_MONOTONIC at the first read
  std::int64_t t0_ns_ = 0;           // t_ns of the first row
};

}  // namespace ve::replay
