// A process' threads as /proc shows them: name, scheduling policy and real-time
// priority, for the tests that check what `run` gives each of its threads.
#pragma once

#include <sys/types.h>

#include <filesystem>
#include <sstream>
#include <string>
#include <vector>

#include "process.hpp"

namespace ve::test {

/// Scheduling policy and RT priority of a task (proc(5) stat fields 41 and 40); both -1
/// when the task has gone (its stat reads empty: a short-lived thread that ended between
/// listing the process' tasks and reading it; taking the empty text apart once threw
/// out of a test in a CI run).
inline void task_sched(const std::string& task, int& policy, int& rt_priority) {
  policy = rt_priority = -1;
  const std::string stat = read_file(task + "/stat");
  const auto name_end = stat.rfind(')');
  if (name_end == std::string::npos || name_end + 2 > stat.size()) return;
  std::istringstream in(stat.substr(name_end + 2));
  std::string f;
  for (int i = 3; i <= 41 && (in >> f); ++i) {
    if (i == 40) rt_priority = std::stoi(f);
    if (i == 41) policy = std::stoi(f);
  }
}

/// Voluntary context switches of a task so far (proc(5) status, voluntary_ctxt_switches):
/// how often it went to sleep, so how often it was woken; -1 when the task has gone.
inline long long voluntary_switches(const std::string& task) {
  std::istringstream in(read_file(task + "/status"));
  std::string line;
  while (std::getline(in, line))
    if (line.rfind("voluntary_ctxt_switches:", 0) == 0) return std::stoll(line.substr(24));
  return -1;
}

/// One thread of a process: its task directory, name, policy and real-time priority.
struct Task {
  std::string dir, comm;
  int policy = -1, prio = -1;
};

/// Every thread of `pid` (none once it has gone).
inline std::vector<Task> tasks_of(pid_t pid) {
  std::vector<Task> out;
  std::error_code ec;
  for (const auto& t : std::filesystem::directory_iterator("/proc/" + std::to_string(pid) + "/task", ec)) {
    Task task;
    task.dir = t.path().string();
    task.comm = read_file(task.dir + "/comm");
    while (!task.comm.empty() && task.comm.back() == '\n') task.comm.pop_back();
    if (task.comm.empty()) continue;  // gone since the listing
    task_sched(task.dir, task.policy, task.prio);
    out.push_back(task);
  }
  return out;
}

/// The task directory of the first thread of `pid` called `comm`; "" if none.
inline std::string find_task(pid_t pid, const std::string& comm) {
  for (const auto& t : tasks_of(pid))
    if (t.comm == comm) return t.dir;
  return {};
}

}  // namespace ve::test
