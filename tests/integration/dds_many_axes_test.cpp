// A machine with more axes than Fast DDS 2.9 lets a reader keep by default: its
// DataReader resource limits allow 10 instances, and every axis is one instance of
// ve/encoder_state (and of the diagnostics and description topics). A reader left at
// those limits silently drops the 11th axis on; the product's readers, built-in and
// from deploy/dds-profiles.xml, must keep every axis of a machine.
#include <gtest/gtest.h>

#include <signal.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <set>
#include <sstream>
#include <string>
#include <thread>

#include "process.hpp"
#include "speed.hpp"
#include "test_domain.hpp"

namespace {

using namespace std::chrono_literals;

constexpr int kAxes = 12;

/// The axis ids of the CSV rows `monitor --csv` printed (first column).
std::set<int> axes_seen(const std::string& csv) {
  std::set<int> ids;
  std::istringstream in(csv);
  std::string line;
  std::getline(in, line);  // header
  while (std::getline(in, line)) {
    char* end = nullptr;
    const long id = std::strtol(line.c_str(), &end, 10);
    if (end != line.c_str() && *end == ',') ids.insert(static_cast<int>(id));
  }
  return ids;
}

void every_axis_reaches(const char* profiles_file) {
  const int domain = ve::test::dds_domain();
  const std::string d = std::to_string(domain);
  const std::string machine = std::string(VE_SOURCE_DIR) + "/tests/integration/data/twelve_axes.yaml";
  const std::string tmp = "/tmp/ve_it_many_axes_" + std::to_string(getpid()) + (profiles_file ? "_profiles" : "");
  if (profiles_file) setenv("FASTRTPS_DEFAULT_PROFILES_FILE", profiles_file, 1);
  ve::test::ChildProcess run({VE_BINARY, "run", "--config", machine, "--domain", d, "--duration", "60"},
                             tmp + ".run.log");
  ve::test::ChildProcess monitor({VE_BINARY, "monitor", "--domain", d, "--csv", "--duration", "60"}, tmp + ".csv",
                                 tmp + ".err");
  if (profiles_file) unsetenv("FASTRTPS_DEFAULT_PROFILES_FILE");
  ASSERT_TRUE(run.started());
  ASSERT_TRUE(monitor.started());
  // Every axis' rows arrive; on a reader that keeps 10 instances, two never do.
  const bool all = ve::test::wait_until(
      [&] { return axes_seen(ve::test::read_file(tmp + ".csv")).size() == kAxes; }, ve::test::patience(30s));
  // Long enough for a few diagnostics periods (0.1 s) of every axis, checked below.
  std::this_thread::sleep_for(500ms);
  monitor.signal(SIGTERM);
  EXPECT_EQ(monitor.wait_exit(ve::test::patience(15s)), 0) << ve::test::read_file(tmp + ".err");
  run.signal(SIGTERM);
  EXPECT_EQ(run.wait_exit(ve::test::patience(15s)), 0) << run.log();
  const auto ids = axes_seen(ve::test::read_file(tmp + ".csv"));
  std::string list;
  for (int id : ids) list += " " + std::to_string(id);
  std::printf("[ figures  ] %s: monitor saw %zu of %d axes:%s\n", profiles_file ? "profiles" : "built-in QoS",
              ids.size(), kAxes, list.c_str());
  EXPECT_TRUE(all) << "monitor saw the axes" << list << "\n" << ve::test::read_file(tmp + ".err");
  for (int id = 1; id <= kAxes; ++id) EXPECT_EQ(ids.count(id), 1u) << "axis " << id << " never reached the monitor";
  // The writers of ve/diagnostics (one instance per axis) keep every axis too: at
  // Fast DDS's default of 10 instances the diagnostics of the 11th axis on fail.
  const std::string log = run.log();
  for (int id = 1; id <= kAxes; ++id) {
    const std::string axis = "axis 'a" + std::to_string(id) + "': ";
    std::string summary;  // "axis 'aN': S samples estimated, P published (F refused by Fast DDS), D diagnostics, ..."
    for (auto at = log.find(axis); at != std::string::npos && summary.empty(); at = log.find(axis, at + 1)) {
      const std::string line = log.substr(at, log.find('\n', at) - at);
      if (line.find(" samples estimated") != std::string::npos) summary = line;
    }
    ASSERT_FALSE(summary.empty()) << axis << "\n" << log;
    EXPECT_EQ(summary.find(" 0 diagnostics"), std::string::npos) << summary;
  }
  std::remove((tmp + ".csv").c_str());
  std::remove((tmp + ".err").c_str());
  std::remove((tmp + ".run.log").c_str());
}

TEST(DdsManyAxes, EveryAxisOfATwelveAxisMachineReachesAReaderWithTheBuiltInQos) { every_axis_reaches(nullptr); }

TEST(DdsManyAxes, EveryAxisOfATwelveAxisMachineReachesAReaderWithTheShippedProfiles) {
  const std::string profiles = std::string(VE_SOURCE_DIR) + "/deploy/dds-profiles.xml";
  every_axis_reaches(profiles.c_str());
}

}  // namespace
