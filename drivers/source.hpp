// The one interface every sensor source implements: simulator, replay, SocketCAN.
// Sources push timestamped samples; the core never pulls from hardware itself.
#pragma once

#include <string>

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

  /// Makes a blocked read() return ReadStatus::stopped. Safe from another thread.
  virtual void stop() {}

  virtual std::string describe() const = 0;
  virtual std::string last_error() const { return {}; }
  /// The driver's own counters in one line (frames, gaps, drops...), for the exit log; "" if none.
  virtual std::string stats() const { return {}; }
};

}  // namespace ve::drivers
