// `run` applies the machine file's `realtime:` section to its sample threads:
// CPU affinity (read back, without privileges, from /proc/PID/task/*/status
// Cpus_allowed_list of the thread named "ve-AXIS"), SCHED_FIFO priority when
// permitted, and one clear warning per setting when it is not, after which the
// run goes on; with `required: true` it fails instead.
#include <gtest/gtest.h>

#include <fcntl.h>
#include <sched.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "process.hpp"
#include "speed.hpp"
#include "temp_dir.hpp"
#include "test_domain.hpp"
#include "threads.hpp"

namespace {

using namespace std::chrono_literals;
using ve::test::find_task;
using ve::test::read_file;
using ve::test::task_sched;
using ve::test::tasks_of;

constexpr int kCapIpcLock = 14;
constexpr int kCapSysNice = 23;

/// Value of a "Key:\tvalue" line of a /proc status file.
std::string status_field(const std::string& status_path, const std::string& key) {
  std::istringstream in(read_file(status_path));
  std::string line;
  while (std::getline(in, line))
    if (line.rfind(key + ":", 0) == 0) {
      std::string v = line.substr(key.size() + 1);
      v.erase(0, v.find_first_not_of(" \t"));
      return v;
    }
  return {};
}

bool has_capability(const std::string& status_path, int cap) {
  const std::string eff = status_field(status_path, "CapEff");
  return !eff.empty() && ((std::stoull(eff, nullptr, 16) >> cap) & 1ULL) != 0;
}

std::string cpu_list(const cpu_set_t& set) {
  std::string s;
  for (int i = 0; i < CPU_SETSIZE;) {
    if (!CPU_ISSET(i, &set)) {
      ++i;
      continue;
    }
    int j = i;
    while (j + 1 < CPU_SETSIZE && CPU_ISSET(j + 1, &set)) ++j;
    s += (s.empty() ? "" : ",") + std::to_string(i) + (j > i ? "-" + std::to_string(j) : "");
    i = j + 1;
  }
  return s;
}

/// In the child, before exec: `virtual-encoder` without the real-time permissions
/// (CAP_SYS_NICE and CAP_IPC_LOCK dropped from the bounding and ambient sets,
/// RLIMIT_RTPRIO 0 and RLIMIT_MEMLOCK 64 KiB).
void drop_realtime_permissions() {
  for (const int cap : {kCapSysNice, kCapIpcLock}) {
    prctl(PR_CAP_AMBIENT, PR_CAP_AMBIENT_LOWER, cap, 0, 0);
    prctl(PR_CAPBSET_DROP, cap, 0, 0, 0);
  }
  rlimit rt{0, 0};
  setrlimit(RLIMIT_RTPRIO, &rt);
  rlimit mem{64 * 1024, 64 * 1024};
  setrlimit(RLIMIT_MEMLOCK, &mem);
}

std::size_t count(const std::string& text, const std::string& what) {
  std::size_t n = 0;
  for (auto p = text.find(what); p != std::string::npos; p = text.find(what, p + 1)) ++n;
  return n;
}

/// A two-axis standstill machine in `dir` whose file starts with `realtime`.
std::string write_machine(const ve::test::TempDir& dir, const std::string& realtime) {
  const std::string motor = std::string(VE_SOURCE_DIR) + "/config/motors/sim-12mm.yaml";
  const std::string path = (dir.path / "machine.yaml").string();
  std::ofstream(path) << "machine: realtime-test\n"
                      << realtime << "axes:\n"
                      << "  - name: x\n    motor: " << motor
                      << "\n    driver: {type: sim, profile: {type: standstill, start_m: 0.3}}\n"
                      << "    homing: {position_m: 0.3}\n"
                      << "  - name: y\n    motor: " << motor
                      << "\n    driver: {type: sim, profile: {type: standstill, start_m: 0.6}}\n"
                      << "    homing: {position_m: 0.6}\n";
  return path;
}

std::vector<std::string> run_args(const std::string& machine) {
  return {VE_BINARY, "run", "--config", machine, "--domain", std::to_string(ve::test::dds_domain()), "--duration", "30"};
}

TEST(Realtime, RunPinsEachSampleThreadToItsCpus) {
  cpu_set_t allowed;
  CPU_ZERO(&allowed);
  ASSERT_EQ(sched_getaffinity(0, sizeof allowed, &allowed), 0);
  int last = -1;
  for (int i = 0; i < CPU_SETSIZE; ++i)
    if (CPU_ISSET(i, &allowed)) last = i;
  ASSERT_GE(last, 0);
  const std::string inherited = cpu_list(allowed);
  if (CPU_COUNT(&allowed) < 2)
    std::printf("[ note     ] only CPU %d is allowed here: pinned and unpinned threads look the same\n", last);

  // x pinned to the last allowed CPU at the lowest FIFO priority; y not named: not pinned.
  // Their CPUs differ, so each has a sample thread of its own.
  ve::test::TempDir dir;
  const std::string machine = write_machine(
      dir, "realtime:\n  sample_thread_priority: 1\n  cpu_affinity: {x: [" + std::to_string(last) + "]}\n");
  ve::test::ChildProcess run(run_args(machine), (dir.path / "run.log").string());
  ASSERT_TRUE(run.started());
  std::string x_task, y_task;
  ASSERT_TRUE(ve::test::wait_until(
      [&] {
        x_task = find_task(run.pid(), "ve-x");
        y_task = find_task(run.pid(), "ve-y");
        return !x_task.empty() && !y_task.empty() && run.log().find("realtime:") != std::string::npos;
      },
      30s))
      << run.log();
  const std::string status_path = "/proc/" + std::to_string(run.pid()) + "/status";
  rlimit rt{};
  getrlimit(RLIMIT_RTPRIO, &rt);
  const bool may = has_capability(status_path, kCapSysNice) || rt.rlim_cur >= 1;
  // The thread is named first and applies its settings right after, before its first
  // sample: wait for them (not for a time) and then judge what is there.
  int policy = -1, prio = -1;
  ve::test::wait_until(
      [&] {
        task_sched(x_task, policy, prio);
        return status_field(x_task + "/status", "Cpus_allowed_list") == std::to_string(last) &&
               (!may || policy == SCHED_FIFO);
      },
      ve::test::patience(10s));
  EXPECT_EQ(status_field(x_task + "/status", "Cpus_allowed_list"), std::to_string(last)) << run.log();
  EXPECT_EQ(status_field(y_task + "/status", "Cpus_allowed_list"), inherited) << "an axis not named is not pinned";
  EXPECT_EQ(status_field(status_path, "Cpus_allowed_list"), inherited) << "the process' other threads are not pinned";

  // The priority: applied when the process may (CAP_SYS_NICE or RLIMIT_RTPRIO >= 1), else one warning.
  task_sched(x_task, policy, prio);
  const std::string log = run.log();
  if (may) {
    EXPECT_EQ(policy, SCHED_FIFO) << log;
    EXPECT_EQ(prio, 1);
    int other_policy = -1, other_prio = -1;
    task_sched("/proc/" + std::to_string(run.pid()) + "/task/" + std::to_string(run.pid()), other_policy, other_prio);
    EXPECT_EQ(other_policy, SCHED_OTHER) << "only the sample threads run at FIFO priority";
    EXPECT_NE(log.find("axis 'x': CPUs " + std::to_string(last) + " SCHED_FIFO 1"), std::string::npos) << log;
  } else {
    EXPECT_EQ(policy, SCHED_OTHER);
    EXPECT_EQ(count(log, "realtime.sample_thread_priority: cannot run"), 1u) << log;
  }
  std::printf("[ figures  ] ve-x: CPUs %s, policy %d priority %d; ve-y: CPUs %s\n",
              status_field(x_task + "/status", "Cpus_allowed_list").c_str(), policy, prio,
              status_field(y_task + "/status", "Cpus_allowed_list").c_str());
  run.signal(SIGTERM);
  EXPECT_EQ(run.wait_exit(15s), 0) << run.log();
}

// Fast DDS's own threads (event, receive) take the writers' locks a sample thread's
// write waits for: with realtime.dds_thread_priority they run at that FIFO priority,
// below the sample threads', every other thread of the process at normal priority.
TEST(Realtime, FastDdsThreadsRunBelowTheSampleThreads) {
  ve::test::TempDir dir;
  const std::string machine =
      write_machine(dir, "realtime:\n  sample_thread_priority: 50\n  dds_thread_priority: 45\n");
  ve::test::ChildProcess run(run_args(machine), (dir.path / "run.log").string());
  ASSERT_TRUE(run.started());
  ASSERT_TRUE(ve::test::wait_until([&] { return run.log().find(" x=") != std::string::npos; }, 30s)) << run.log();
  const std::string status_path = "/proc/" + std::to_string(run.pid()) + "/status";
  rlimit rt{};
  getrlimit(RLIMIT_RTPRIO, &rt);
  if (!has_capability(status_path, kCapSysNice) && (rt.rlim_cur == RLIM_INFINITY ? false : rt.rlim_cur < 50))
    GTEST_SKIP() << "no permission for SCHED_FIFO 50 here";
  int at_50 = 0, at_45 = 0, other_fifo = 0;
  std::string seen;
  for (const auto& t : tasks_of(run.pid())) {
    seen += t.comm + " " + std::to_string(t.policy) + "/" + std::to_string(t.prio) + "; ";
    if (t.policy == SCHED_FIFO && t.prio == 50 && t.comm.rfind("ve-", 0) == 0)
      ++at_50;
    else if (t.policy == SCHED_FIFO && t.prio == 45 && t.comm.rfind("ve-", 0) != 0)
      ++at_45;
    else if (t.policy != SCHED_OTHER)
      ++other_fifo;
  }
  EXPECT_EQ(at_50, 1) << "one sample thread for x and y: " << seen;
  EXPECT_GE(at_45, 3) << "Fast DDS's event thread and its receive threads: " << seen;
  EXPECT_EQ(other_fifo, 0) << seen;
  int main_policy = -1, main_prio = -1;
  task_sched("/proc/" + std::to_string(run.pid()) + "/task/" + std::to_string(run.pid()), main_policy, main_prio);
  EXPECT_EQ(main_policy, SCHED_OTHER) << "the main thread is back at normal priority once the DDS entities exist";
  EXPECT_NE(run.log().find("Fast DDS's threads SCHED_FIFO 45"), std::string::npos) << run.log();
  std::printf("[ figures  ] threads: %s\n", seen.c_str());
  run.signal(SIGTERM);
  EXPECT_EQ(run.wait_exit(15s), 0) << run.log();

  // Not given (0): they stay at normal priority.
  ve::test::TempDir dir0;
  const std::string machine0 = write_machine(dir0, "realtime:\n  sample_thread_priority: 50\n");
  ve::test::ChildProcess run0(run_args(machine0), (dir0.path / "run.log").string());
  ASSERT_TRUE(run0.started());
  ASSERT_TRUE(ve::test::wait_until([&] { return run0.log().find(" x=") != std::string::npos; }, 30s)) << run0.log();
  std::string seen0;
  int fifo0 = 0;
  for (const auto& t : tasks_of(run0.pid())) {
    seen0 += t.comm + " " + std::to_string(t.policy) + "/" + std::to_string(t.prio) + "; ";
    if (t.policy != SCHED_OTHER && t.comm.rfind("ve-", 0) != 0) ++fifo0;
  }
  EXPECT_EQ(fifo0, 0) << seen0;
  run0.signal(SIGTERM);
  EXPECT_EQ(run0.wait_exit(15s), 0) << run0.log();
}

TEST(Realtime, WithoutPermissionWarnsOncePerSettingAndPublishes) {
  ve::test::TempDir dir;
  const std::string machine = write_machine(dir, "realtime:\n  sample_thread_priority: 50\n  lock_memory: true\n");
  ve::test::ChildProcess run(run_args(machine), (dir.path / "run.log").string(), "", drop_realtime_permissions);
  ASSERT_TRUE(run.started());
  // x and y share one sample thread (realtime.sample_loop: shared), named after x and the one other axis.
  std::string x_task;
  ASSERT_TRUE(ve::test::wait_until([&] { return !(x_task = find_task(run.pid(), "ve-x+1")).empty(); }, 30s))
      << run.log();
  const std::string status_path = "/proc/" + std::to_string(run.pid()) + "/status";
  if (has_capability(status_path, kCapSysNice) || has_capability(status_path, kCapIpcLock))
    GTEST_SKIP() << "cannot drop CAP_SYS_NICE / CAP_IPC_LOCK for the child here";
  int policy = -1, prio = -1;
  task_sched(x_task, policy, prio);
  EXPECT_EQ(policy, SCHED_OTHER);
  // It goes on: the status lines show samples (rate > 0) and it stops cleanly.
  ASSERT_TRUE(ve::test::wait_until([&] { return run.log().find(" x=") != std::string::npos; }, 30s)) << run.log();
  run.signal(SIGTERM);
  EXPECT_EQ(run.wait_exit(15s), 0) << run.log();
  const std::string log = run.log();
  EXPECT_EQ(count(log, "realtime.sample_thread_priority: cannot run the sample threads at SCHED_FIFO priority 50"), 1u)
      << "one warning for two axes:\n" << log;
  EXPECT_NE(log.find("CAP_SYS_NICE or RLIMIT_RTPRIO >= 50 (now 0"), std::string::npos) << log;
  EXPECT_EQ(count(log, "realtime.lock_memory: cannot lock the process' memory"), 1u) << log;
  EXPECT_NE(log.find("going on without it"), std::string::npos) << log;
  EXPECT_EQ(log.find("not starting"), std::string::npos) << log;
  EXPECT_NE(log.find("published "), std::string::npos) << log;
  EXPECT_EQ(log.find("published 0 samples"), std::string::npos) << log;
}

TEST(Realtime, RequiredSettingWithoutPermissionFailsTheRun) {
  ve::test::TempDir dir;
  const std::string machine = write_machine(dir, "realtime:\n  sample_thread_priority: 50\n  required: true\n");
  ve::test::ChildProcess run(run_args(machine), (dir.path / "run.log").string(), "", drop_realtime_permissions);
  ASSERT_TRUE(run.started());
  const int rc = run.wait_exit(30s);
  const std::string log = run.log();
  if (rc == -1 || log.find("SCHED_FIFO 50") != std::string::npos)
    GTEST_SKIP() << "the child kept CAP_SYS_NICE here:\n" << log;
  EXPECT_EQ(rc, 1) << log;
  EXPECT_NE(log.find("realtime.sample_thread_priority: cannot run"), std::string::npos) << log;
  EXPECT_NE(log.find("realtime.required is true: not starting"), std::string::npos) << log;
  EXPECT_EQ(log.find(" x="), std::string::npos) << "no sample thread ran:\n" << log;
}

}  // namespace
