// Supervision by systemd (Type=notify): readiness once every axis publishes, the
// watchdog petted only while every sample loop makes progress, and a stopping
// notice on SIGTERM. Does nothing when not started by systemd (no NOTIFY_SOCKET).
#pragma once

#include <string>

namespace ve::app {

class ServiceNotifier {
 public:
  ServiceNotifier();
  bool enabled() const { return enabled_; }
  /// Half the watchdog interval systemd asked for [s]; 0 when there is no watchdog.
  double watchdog_period_s() const { return watchdog_period_s_; }
  void ready(const std::string& status);
  void watchdog();
  void status(const std::string& status);
  void stopping();

 private:
  bool enabled_ = false;
  double watchdog_period_s_ = 0.0;
};

}  // namespace ve::app
