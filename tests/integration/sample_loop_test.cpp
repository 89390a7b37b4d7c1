// One paced loop for many axes (realtime.sample_loop): the simulated axes of a machine
// whose rates divide each other's are read, estimated and published by one sample
// thread, one wake-up per tick; an axis of another rate gets a thread of its own.
// What is checked is behaviour, not timing: the grouping `run` logs, every axis'
// samples with consecutive sequence numbers and exact sample instants, and, within one
// loop, the axes handed over in the machine file's order and back, tick after tick.
#include <gtest/gtest.h>

#include <signal.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include "process.hpp"
#include "speed.hpp"
#include "temp_dir.hpp"
#include "test_domain.hpp"

namespace {

using namespace std::chrono_literals;
using ve::test::ChildProcess;

std::string data(const std::string& name) { return std::string(VE_SOURCE_DIR) + "/tests/integration/data/" + name; }

struct Row {
  unsigned long long sequence = 0;
  long long sample_time_ns = 0;
  long long source_time_ns = 0;
};

/// `monitor --csv` rows by axis id, in the order received.
std::map<int, std::vector<Row>> rows_by_axis(const std::string& csv) {
  std::map<int, std::vector<Row>> out;
  std::istringstream in(csv);
  std::string line;
  std::getline(in, line);  // header
  while (std::getline(in, line)) {
    std::vector<std::string> f;
    std::stringstream ls(line);
    std::string item;
    while (std::getline(ls, item, ',')) f.push_back(item);
    if (f.size() != 14) continue;  // a row being written
    Row r;
    r.sequence = std::strtoull(f[1].c_str(), nullptr, 10);
    r.sample_time_ns = std::strtoll(f[2].c_str(), nullptr, 10);
    r.source_time_ns = std::strtoll(f[12].c_str(), nullptr, 10);
    out[std::atoi(f[0].c_str())].push_back(r);
  }
  return out;
}

/// Runs `machine` with a `monitor --csv` that is matched before the first sample, until
/// every axis of `ids` has `rows` rows; returns run's log and the rows.
struct Stream {
  std::string log;
  std::map<int, std::vector<Row>> rows;
  int run_exit = -1;
};

Stream stream(const std::string& machine, const std::vector<int>& ids, std::size_t rows) {
  const int domain = ve::test::dds_domain();
  const std::string d = std::to_string(domain);
  ve::test::TempDir dir("ve_it_sample_loop");
  const std::string csv = dir.file("monitor.csv");
  ChildProcess monitor({VE_BINARY, "monitor", "--domain", d, "--csv", "--duration", "120"}, csv,
                       dir.file("monitor.err"));
  ChildProcess run({VE_BINARY, "run", "--config", machine, "--domain", d, "--duration", "60", "--wait-for-subscriber",
                    "20"},
                   dir.file("run.log"));
  Stream s;
  if (!monitor.started() || !run.started()) return s;
  ve::test::wait_until(
      [&] {
        const auto by_axis = rows_by_axis(ve::test::read_file(csv));
        for (int id : ids) {
          const auto it = by_axis.find(id);
          if (it == by_axis.end() || it->second.size() < rows) return false;
        }
        return true;
      },
      ve::test::patience(40s));
  run.signal(SIGTERM);
  s.run_exit = run.wait_exit(ve::test::patience(15s));
  monitor.signal(SIGTERM);
  monitor.wait_exit(ve::test::patience(15s));
  s.log = run.log();
  s.rows = rows_by_axis(ve::test::read_file(csv));
  return s;
}

/// Every row's sample instant is the exact one of its sequence number (sample
/// sequence - 1 of a clock started at 0, rounded to the ns as the simulator does), the
/// sequence numbers rise, and at most `max_gap_share` of them are missing (the
/// stream is best effort). Returns the number of missing samples.
std::size_t check_axis(int id, const std::vector<Row>& rows, double rate_hz, double max_gap_share = 0.01) {
  EXPECT_FALSE(rows.empty()) << "axis " << id;
  if (rows.empty()) return 0;
  std::size_t missing = 0;
  for (std::size_t i = 0; i < rows.size(); ++i) {
    const Row& r = rows[i];
    const auto exact = static_cast<long long>(std::llround(static_cast<long double>(r.sequence - 1) * 1e9L / rate_hz));
    EXPECT_EQ(r.sample_time_ns, exact) << "axis " << id << " sequence " << r.sequence;
    if (i == 0) continue;
    const Row& p = rows[i - 1];
    EXPECT_GT(r.sequence, p.sequence) << "axis " << id;
    EXPECT_GE(r.source_time_ns, p.source_time_ns) << "axis " << id << " sequence " << r.sequence;
    if (r.sequence > p.sequence + 1) missing += r.sequence - p.sequence - 1;
  }
  const double span = static_cast<double>(rows.back().sequence - rows.front().sequence + 1);
  const double mean_spacing_us = rows.size() > 1 ? 1e-3 * static_cast<double>(rows.back().source_time_ns -
                                                                              rows.front().source_time_ns) /
                                                       static_cast<double>(rows.back().sequence - rows.front().sequence)
                                                 : 0.0;
  std::printf("[ figures  ] axis %d: %zu rows, sequences %llu..%llu, %zu missing, source_time spacing %.1f us "
              "(period %.1f us)\n",
              id, rows.size(), rows.front().sequence, rows.back().sequence, missing, mean_spacing_us, 1e6 / rate_hz);
  // How many the best-effort stream lost is a real-time figure: judged at real speed only
  // (speed.hpp; under a sanitizer the loop falls behind its 4 kHz and skips).
  if (ve::test::kRealTimeFigures) EXPECT_LE(static_cast<double>(missing), max_gap_share * span) << "axis " << id;
  return missing;
}

TEST(SampleLoop, ThreeAxesOfOneRateAreSteppedInOneThreadInTheMachineFilesOrderAndBack) {
  const ve::test::RealTimeSlot real_time;  // compares the axes of one stream (speed.hpp)
  const Stream s = stream(data("three_axes.yaml"), {1, 2, 3}, 8000);
  EXPECT_EQ(s.run_exit, 0) << s.log;
  EXPECT_NE(s.log.find("sample thread 've-x+2': 3 axes 'x', 'y', 'z' in one loop at 4000 Hz"), std::string::npos)
      << s.log;
  for (int id : {1, 2, 3}) {
    const auto it = s.rows.find(id);
    ASSERT_NE(it, s.rows.end()) << "axis " << id << " never reached the monitor\n" << s.log;
    check_axis(id, it->second, 4000.0);
  }
  // One thread steps x, y, z in turn on every tick, in the machine file's order and in
  // the reverse order every other tick (GroupWriteOrder: one deadline re-arm per tick):
  // the hand-over instants (source_time_ns) of a tick are x's, y's, z's, or z's, y's,
  // x's, never another order, and two consecutive ticks go opposite ways.
  std::map<long long, long long> source_of[3];
  for (int id : {1, 2, 3})
    for (const Row& r : s.rows.at(id)) source_of[id - 1][r.sample_time_ns] = r.source_time_ns;
  std::size_t ticks = 0, forwards = 0, backwards = 0, pairs = 0, alternating = 0;
  long long last_t = 0;
  int last_way = 0;  // 1 forwards, -1 backwards, 0 neither
  const long long period_ns = 250000;
  for (const auto& [t, x] : source_of[0]) {
    const auto y = source_of[1].find(t), z = source_of[2].find(t);
    if (y == source_of[1].end() || z == source_of[2].end()) continue;
    ++ticks;
    int way = 0;
    if (x <= y->second && y->second <= z->second) way = 1;
    else if (z->second <= y->second && y->second <= x) way = -1;
    forwards += way == 1;
    backwards += way == -1;
    if (way != 0 && last_way != 0 && t - last_t == period_ns) {
      ++pairs;
      alternating += way != last_way;
    }
    last_t = t;
    last_way = way;
  }
  std::printf("[ figures  ] %zu ticks seen on all three axes, %zu handed over in the order x, y, z and %zu in the "
              "order z, y, x; %zu of %zu consecutive ticks went opposite ways\n",
              ticks, forwards, backwards, alternating, pairs);
  EXPECT_GT(ticks, 4000u);
  EXPECT_EQ(forwards + backwards, ticks);
  EXPECT_GT(pairs, 1000u);
  EXPECT_EQ(alternating, pairs);
}

TEST(SampleLoop, AxesOfRatesThatDivideShareAThreadAndAnotherRateGetsItsOwn) {
  const ve::test::RealTimeSlot real_time;
  const Stream s = stream(data("mixed_rates.yaml"), {1, 2, 3}, 2000);
  EXPECT_EQ(s.run_exit, 0) << s.log;
  EXPECT_NE(s.log.find("sample thread 've-x+1': 2 axes 'x', 'y' in one loop at 4000 Hz"), std::string::npos) << s.log;
  EXPECT_NE(s.log.find("sample thread 've-z': axis 'z' alone at 3000 Hz (no other axis shares its rate and CPUs)"),
            std::string::npos)
      << s.log;
  const double rates[] = {4000.0, 1000.0, 3000.0};
  for (int id : {1, 2, 3}) {
    const auto it = s.rows.find(id);
    ASSERT_NE(it, s.rows.end()) << "axis " << id << " never reached the monitor\n" << s.log;
    check_axis(id, it->second, rates[id - 1]);
  }
}

TEST(SampleLoop, PerAxisGivesEveryAxisItsOwnThread) {
  ve::test::TempDir dir("ve_it_sample_loop_per_axis");
  // three_axes.yaml in a scratch directory, its relative paths made absolute.
  std::string machine = ve::test::read_file(data("three_axes.yaml"));
  for (std::size_t at; (at = machine.find("../../../")) != std::string::npos;)
    machine.replace(at, 9, std::string(VE_SOURCE_DIR) + "/");
  const std::string file = dir.write("machine.yaml", machine + "\nrealtime:\n  sample_loop: per_axis\n");
  const int domain = ve::test::dds_domain();
  ChildProcess run({VE_BINARY, "run", "--config", file, "--domain", std::to_string(domain), "--duration", "2"},
                   dir.file("run.log"));
  ASSERT_TRUE(run.started());
  const int rc = run.wait_exit(ve::test::patience(30s));
  const std::string log = run.log();
  EXPECT_EQ(rc, 0) << log;
  for (const char* axis : {"x", "y", "z"}) {
    const std::string line = std::string("sample thread 've-") + axis + "': axis '" + axis +
                             "' alone at 4000 Hz (realtime.sample_loop: per_axis)";
    EXPECT_NE(log.find(line), std::string::npos) << line << "\n" << log;
    const std::string estimated = std::string("axis '") + axis + "': ";
    const auto at = log.find(estimated + "0 samples estimated");
    EXPECT_EQ(at, std::string::npos) << log;
  }
  EXPECT_EQ(log.find("in one loop"), std::string::npos) << log;
}

}  // namespace
