// Real-time settings of `run`, from the machine file's `realtime:` section:
// memory locked (mlockall) once for the process, SCHED_FIFO priority and CPU
// affinity for each sample thread (one per group of axes, realtime.sample_loop),
// and a SCHED_FIFO priority below the sample threads' for Fast DDS's own threads
// (realtime.dds_thread_priority). Fast DDS 2.9 has no setting for its threads'
// scheduling; they inherit the policy of the thread that creates the participant,
// so `run` creates its DDS entities between begin_dds_threads() and end_dds_threads().
//
// Permissions: SCHED_FIFO needs CAP_SYS_NICE or RLIMIT_RTPRIO >= the priority;
// locking all memory needs CAP_IPC_LOCK or an RLIMIT_MEMLOCK above the process'
// size. The systemd unit grants both. Without them, each setting that cannot be
// applied is logged once as a warning naming it and the run goes on without it,
// unless `realtime.required: true`, which makes `run` fail before any sample
// thread starts.
#pragma once

#include <pthread.h>

#include <atomic>
#include <string>
#include <vector>

#include "config/machine_config.hpp"

namespace ve::app {

class Realtime {
 public:
  /// Locks memory (if asked) and checks, on a short-lived probe thread per axis,
  /// that every sample thread's priority and affinity can be applied; logs one
  /// warning per setting that cannot.
  Realtime(const config::RealtimeConfig& config, const std::vector<std::string>& axes);

  /// false when `required` is set and some setting cannot be applied (already logged).
  bool ok() const { return ok_; }

  /// Called first thing in an axis' sample thread: names the thread "ve-AXIS"
  /// (seen in /proc/PID/task/*/comm, ps -L, top -H) and applies its affinity and
  /// priority. Settings the probe found impossible are not tried again.
  /// A thread that steps several axes (realtime.sample_loop: shared) enters as its
  /// first axis (they share CPUs and priority) and is named `thread_name` if not empty.
  void enter_sample_thread(const std::string& axis, const std::string& thread_name = std::string());

  /// A thread of an axis' source that its sample thread waits for (SocketCAN's receive
  /// thread, drivers::SensorSource::helper_threads): named "ve-rx-AXIS" and given the
  /// axis' sample thread's CPUs and priority, from the thread that calls this.
  void adopt_source_thread(pthread_t thread, const std::string& axis);

  /// The calling thread takes Fast DDS's threads' priority (if any and permitted), so
  /// that the threads Fast DDS starts from it inherit it ...
  void begin_dds_threads();
  /// ... and goes back to normal scheduling.
  void end_dds_threads();

 private:
  /// Names `thread` and gives it `axis`' CPUs and priority (what the probe allowed);
  /// "" or what failed, for the log.
  std::string apply_axis_settings(pthread_t thread, const std::string& axis, const std::string& name);

  config::RealtimeConfig config_;
  bool ok_ = true;
  bool priority_usable_ = true;
  bool dds_priority_usable_ = true;
  std::vector<std::string> affinity_unusable_;  ///< axes whose CPUs cannot be used
  std::atomic<bool> late_warning_{false};
};

/// The calling thread back to normal scheduling (SCHED_OTHER), e.g. a worker started
/// from a thread at a real-time priority, which it would otherwise inherit.
void set_normal_scheduling();

/// "0-2,5": a CPU list in the kernel's Cpus_allowed_list form.
std::string format_cpu_list(const std::vector<int>& cpus);

}  // namespace ve::app
