// The one interface every sensor source implements: simulator, replay, SocketCAN.
// Sources push timestamped samples; the core never pulls from hardware itself.
#pragma once

#include <pthread.h>

#include <cstdint>
#include <string>
#include <vector>

#include "core/sample.hpp"

namespace ve::drivers {

enum class ReadStatus {
  ok,             ///< sample filled in
  timeout,        ///< nothing arrived in time; the caller decides what a silent sensor means
  end_of_stream,  ///< a finite source (replay) is exhausted
  stopped,        ///< stop() was called
  error,          ///< unrecoverable; last_error() says why
};

class SensorSource {
 public:
  SensorSource() = default;
  SensorSource(const SensorSource&) = delete;
  SensorSource& operator=(const SensorSource&) = delete;
  virtual ~SensorSource() = default;

  /// Blocks until the next sample is available (a real-time source waits for its
  /// sample instant), then fills `out`. Never allocates.
  virtual ReadStatus read(core::RawSample& out) = 0;

  /// Ground truth for the sample last read, where the source knows it (simulator,
  /// logs with truth columns); nullptr otherwise.
  virtual const core::Truth* truth() const { return nullptr; }

  /// Reference ruler position for the sample last read, where one is available
  /// (calibration with a reference: the simulator's exact position, a log's
  /// ref_position_m column). False when there is none for this sample.
  virtual bool reference_position(double& position_m) const {
    (void)position_m;
    return false;
  }

  /// Sources paced by the clock rather than by data arriving (the simulator in real
  /// time) can be read in turn from one thread that waits once per tick for all of
  /// them. share_clock(start_ns), before the first read(), starts the source's clock
  /// at `start_ns` [CLOCK_MONOTONIC ns]: sample n is due at start_ns plus its offset.
  /// From then on read() does not wait: the caller waits until next_due_ns() first.
  /// False, and nothing changed, for a source that waits for data of its own
  /// (SocketCAN, a replayed log) or is not paced at all.
  virtual bool share_clock(std::int64_t start_ns) {
    (void)start_ns;
    return false;
  }
  /// With a shared clock: the CLOCK_MONOTONIC instant [ns] from which read() returns
  /// without waiting (the next sample, a timeout while the source is silent, or the
  /// end of the stream); 0: at once. Never allocates.
  virtual std::int64_t next_due_ns() const { return 0; }

  /// Makes a blocked read() return ReadStatus::stopped. Safe from another thread.
  virtual void stop() {}

  /// Threads of the source's own that read() waits for (SocketCAN's receive thread):
  /// part of the sample path, so `run` gives them the axis' sample thread's real-time
  /// settings. Empty: read() waits for nothing but the clock or its caller.
  virtual std::vector<pthread_t> helper_threads() { return {}; }

  virtual std::string describe() const = 0;
  virtual std::string last_error() const { return {}; }
  /// The driver's own counters in one line (frames, gaps, drops...), for the exit log; "" if none.
  virtual std::string stats() const { return {}; }
};

}  // namespace ve::drivers
