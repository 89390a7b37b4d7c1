#include "realtime.hpp"

#include <pthread.h>
#include <sched.h>
#include <sys/mman.h>
#include <sys/resource.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <fstream>
#include <string>
#include <thread>

#include <spdlog/spdlog.h>

namespace ve::app {

namespace {

constexpr int kCapIpcLock = 14;  // linux/capability.h
constexpr int kCapSysNice = 23;

/// Whether this process has a capability in its effective set (/proc/self/status CapEff).
bool has_capability(int cap) {
  std::ifstream in("/proc/self/status");
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind("CapEff:", 0) != 0) continue;
    const unsigned long long eff = std::strtoull(line.c_str() + 7, nullptr, 16);
    return ((eff >> cap) & 1ULL) != 0;
  }
  return false;
}

std::string limit_text(int resource, bool bytes) {
  rlimit r{};
  if (getrlimit(resource, &r) != 0) return "unknown";
  if (r.rlim_cur == RLIM_INFINITY) return "unlimited";
  if (bytes) return std::to_string(r.rlim_cur / 1024) + " KiB";
  return std::to_string(r.rlim_cur);
}

std::vector<int> cpus_of(const cpu_set_t& set) {
  std::vector<int> cpus;
  for (int i = 0; i < CPU_SETSIZE; ++i)
    if (CPU_ISSET(i, &set)) cpus.push_back(i);
  return cpus;
}

/// Sets a thread's affinity; 0 or an errno. `got` is what the kernel kept.
int set_affinity(pthread_t thread, const std::vector<int>& cpus, std::vector<int>& got) {
  cpu_set_t set;
  CPU_ZERO(&set);
  for (const int c : cpus)
    if (c >= 0 && c < CPU_SETSIZE) CPU_SET(c, &set);
  const int rc = pthread_setaffinity_np(thread, sizeof set, &set);
  if (rc != 0) return rc;
  cpu_set_t now;
  CPU_ZERO(&now);
  if (pthread_getaffinity_np(thread, sizeof now, &now) == 0) got = cpus_of(now);
  return 0;
}

int set_fifo(pthread_t thread, int priority) {
  sched_param p{};
  p.sched_priority = priority;
  return pthread_setschedparam(thread, SCHED_FIFO, &p);
}

struct ProbeResult {
  int affinity_error = 0;
  std::vector<int> affinity_got;
  int priority_error = 0;
};

}  // namespace

std::string format_cpu_list(const std::vector<int>& cpus_in) {
  std::vector<int> cpus = cpus_in;
  std::sort(cpus.begin(), cpus.end());
  std::string s;
  for (std::size_t i = 0; i < cpus.size();) {
    std::size_t j = i;
    while (j + 1 < cpus.size() && cpus[j + 1] == cpus[j] + 1) ++j;
    if (!s.empty()) s += ",";
    s += std::to_string(cpus[i]);
    if (j > i) s += "-" + std::to_string(cpus[j]);
    i = j + 1;
  }
  return s;
}

Realtime::Realtime(const config::RealtimeConfig& config, const std::vector<std::string>& axes) : config_(config) {
  const char* consequence = config_.required ? "realtime.required is true: not starting"
                                             : "going on without it";
  auto problem = [&](const std::string& text) {
    if (config_.required) {
      spdlog::error("{}; {}", text, consequence);
      ok_ = false;
    } else {
      spdlog::warn("{}; {}", text, consequence);
    }
  };

  bool locked = false;
  if (config_.lock_memory) {
    locked = mlockall(MCL_CURRENT | MCL_FUTURE) == 0;
    if (!locked) {
      const int e = errno;
      problem(std::string("realtime.lock_memory: cannot lock the process' memory (mlockall: ") + std::strerror(e) +
              "); it needs CAP_IPC_LOCK or an RLIMIT_MEMLOCK above the process' size (now " +
              limit_text(RLIMIT_MEMLOCK, true) + "; the systemd unit grants both)");
    } else if (!has_capability(kCapIpcLock) && limit_text(RLIMIT_MEMLOCK, true) != "unlimited") {
      spdlog::warn("realtime.lock_memory: memory locked under a finite RLIMIT_MEMLOCK ({}) without CAP_IPC_LOCK: "
                   "an allocation beyond it will fail",
                   limit_text(RLIMIT_MEMLOCK, true));
    }
  }

  // Probe: the settings each sample thread will take, tried on a throwaway
  // thread, so that a missing permission is known (and, with `required`, fatal)
  // before any sample thread runs.
  const int priority = config_.sample_thread_priority;
  bool priority_warned = false;
  std::vector<std::string> applied;
  for (const auto& axis : axes) {
    const std::vector<int>& cpus = config_.cpus_for(axis);
    if (cpus.empty() && priority <= 0) continue;
    ProbeResult r;
    std::thread probe([&] {
      if (!cpus.empty()) r.affinity_error = set_affinity(pthread_self(), cpus, r.affinity_got);
      if (priority > 0) r.priority_error = set_fifo(pthread_self(), priority);
    });
    probe.join();
    std::string line = "axis '" + axis + "':";
    if (!cpus.empty()) {
      if (r.affinity_error != 0) {
        affinity_unusable_.push_back(axis);
        problem("realtime.cpu_affinity: cannot pin the sample thread of axis '" + axis + "' to CPUs " +
                format_cpu_list(cpus) + " (" + std::strerror(r.affinity_error) +
                "; none of them is allowed to this process, e.g. by a cgroup cpuset)");
      } else {
        if (r.affinity_got != cpus && !r.affinity_got.empty()) {
          std::vector<int> sorted = cpus;
          std::sort(sorted.begin(), sorted.end());
          if (r.affinity_got != sorted)
            spdlog::warn("realtime.cpu_affinity: axis '{}' asked for CPUs {}, the kernel allows only {} to this process",
                         axis, format_cpu_list(cpus), format_cpu_list(r.affinity_got));
        }
        line += " CPUs " + format_cpu_list(r.affinity_got.empty() ? cpus : r.affinity_got);
      }
    }
    if (priority > 0) {
      if (r.priority_error != 0) {
        priority_usable_ = false;
        if (!priority_warned) {
          priority_warned = true;
          problem("realtime.sample_thread_priority: cannot run the sample threads at SCHED_FIFO priority " +
                  std::to_string(priority) + " (" + std::strerror(r.priority_error) +
                  "); it needs CAP_SYS_NICE or RLIMIT_RTPRIO >= " + std::to_string(priority) + " (now " +
                  limit_text(RLIMIT_RTPRIO, false) + (has_capability(kCapSysNice) ? ", CAP_SYS_NICE held" : ", no CAP_SYS_NICE") +
                  "; the systemd unit grants both); they run at normal priority" +
                  (config_.dds_thread_priority > 0 ? std::string(", and so do Fast DDS's threads") : ""));
        }
      } else {
        line += " SCHED_FIFO " + std::to_string(priority);
      }
    }
    applied.push_back(line);
  }
  // Fast DDS's threads, below the sample threads: tried the same way.
  // Never above sample threads that could not have their own priority.
  const int dds_priority = config_.dds_thread_priority;
  if (dds_priority > 0 && !priority_usable_) dds_priority_usable_ = false;
  if (dds_priority > 0 && priority_usable_) {
    int rc = 0;
    std::thread probe([&] { rc = set_fifo(pthread_self(), dds_priority); });
    probe.join();
    if (rc != 0) {
      dds_priority_usable_ = false;
      problem("realtime.dds_thread_priority: cannot run Fast DDS's threads at SCHED_FIFO priority " +
                std::to_string(dds_priority) + " (" + std::strerror(rc) + "); it needs CAP_SYS_NICE or RLIMIT_RTPRIO >= " +
                std::to_string(dds_priority) + " (now " + limit_text(RLIMIT_RTPRIO, false) +
                "); they run at normal priority");
    } else {
      applied.push_back("Fast DDS's threads SCHED_FIFO " + std::to_string(dds_priority));
    }
  } else if (dds_priority <= 0 && priority_usable_ && config_.sample_thread_priority > 0) {
    // Said, not warned: a choice the machine file may make. What it costs is measured in
    // docs/scale.md (the plant test's deadline misses with no stall of the host).
    applied.push_back("Fast DDS's threads at normal priority (a sample thread's write waits for locks they hold; "
                      "realtime.dds_thread_priority raises them)");
  }
  if (!ok_) return;
  std::string summary;
  for (const auto& a : applied) summary += (summary.empty() ? " " : "; ") + a;
  if (config_.any())
    spdlog::info("realtime:{}{}", summary.empty() ? std::string(" sample threads not pinned, normal priority") : summary,
                 locked ? "; memory locked" : "");
}

std::string Realtime::apply_axis_settings(pthread_t thread, const std::string& axis, const std::string& name) {
  pthread_setname_np(thread, name.c_str());
  const std::vector<int>& cpus = config_.cpus_for(axis);
  const bool affinity = !cpus.empty() &&
                        std::find(affinity_unusable_.begin(), affinity_unusable_.end(), axis) == affinity_unusable_.end();
  std::vector<int> got;
  const int ea = affinity ? set_affinity(thread, cpus, got) : 0;
  const int ep =
      (config_.sample_thread_priority > 0 && priority_usable_) ? set_fifo(thread, config_.sample_thread_priority) : 0;
  return std::string(ea ? std::string("cpu_affinity failed: ") + std::strerror(ea) + " " : "") +
         (ep ? std::string("sample_thread_priority failed: ") + std::strerror(ep) : "");
}

void Realtime::adopt_source_thread(pthread_t thread, const std::string& axis) {
  const std::string name = ("ve-rx-" + axis).substr(0, 15);
  const std::string failed = apply_axis_settings(thread, axis, name);
  if (!failed.empty())
    spdlog::warn("realtime: axis '{}': its source's thread {}: {}", axis, name, failed);
  else if (config_.sample_thread_priority > 0 || !config_.cpus_for(axis).empty())
    spdlog::info("realtime: axis '{}': its source's thread {} with the sample thread's settings", axis, name);
}

void Realtime::begin_dds_threads() {
  const int priority = config_.dds_thread_priority;
  if (priority <= 0 || !dds_priority_usable_) return;
  if (const int rc = set_fifo(pthread_self(), priority))
    spdlog::warn("realtime: Fast DDS's threads at normal priority: {}", std::strerror(rc));
}

void Realtime::end_dds_threads() {
  if (config_.dds_thread_priority <= 0 || !dds_priority_usable_) return;
  set_normal_scheduling();
}

void set_normal_scheduling() {
  sched_param p{};
  p.sched_priority = 0;
  pthread_setschedparam(pthread_self(), SCHED_OTHER, &p);
}

void Realtime::enter_sample_thread(const std::string& axis, const std::string& thread_name) {
  const std::string name = (thread_name.empty() ? "ve-" + axis : thread_name).substr(0, 15);
  const std::string failed = apply_axis_settings(pthread_self(), axis, name);
  if (!failed.empty() && !late_warning_.exchange(true)) spdlog::warn("realtime: axis '{}': {}", axis, failed);
}

}  // namespace ve::app
