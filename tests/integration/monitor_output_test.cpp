// What `monitor` prints is what it says it prints:
//  - `monitor --csv` writes CSV and nothing else on stdout, also while Fast DDS logs:
//    the monitor is given a profiles file Fast DDS complains about (an unknown element:
//    Fast DDS's XML parser logs an error and the monitor goes on with its built-in QoS),
//    and Fast DDS's lines must come out on stderr, through the product's logger;
//  - an encoder with one axis is one state writer: the monitor, which logs how many
//    state writers it matched, matches one (each axis once had a second writer that
//    never wrote).
#include <gtest/gtest.h>

#include <signal.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "process.hpp"
#include "speed.hpp"
#include "test_domain.hpp"

namespace {

using namespace std::chrono_literals;

std::vector<std::string> split(const std::string& line) {
  std::vector<std::string> f;
  std::string cell;
  std::istringstream in(line);
  while (std::getline(in, cell, ',')) f.push_back(cell);
  if (!line.empty() && line.back() == ',') f.push_back("");
  return f;
}

bool is_number(const std::string& s) {
  if (s.empty()) return false;
  char* end = nullptr;
  if (s.rfind("0x", 0) == 0) {
    std::strtoull(s.c_str() + 2, &end, 16);
  } else {
    std::strtod(s.c_str(), &end);
  }
  return end != nullptr && *end == '\0';
}

TEST(MonitorOutput, CsvStaysCleanWhileFastDdsLogsAndOneStateWriterPerAxis) {
  const int domain = ve::test::dds_domain();
  const std::string d = std::to_string(domain);
  const std::string machine = std::string(VE_SOURCE_DIR) + "/tests/integration/data/standstill.yaml";
  const std::string tmp = "/tmp/ve_it_monitor_output_" + std::to_string(getpid());
  const std::string bad_profiles = tmp + ".profiles.xml";
  {
    std::ofstream f(bad_profiles);
    f << "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
         "<dds xmlns=\"http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles\"><profiles>\n"
         "  <participant profile_name=\"ve_participant\"><rtps><no_such_element/></rtps></participant>\n"
         "</profiles></dds>\n";
  }
  ve::test::ChildProcess run({VE_BINARY, "run", "--config", machine, "--domain", d, "--duration", "60"},
                             tmp + ".run.log");
  ASSERT_TRUE(run.started());
  setenv("FASTRTPS_DEFAULT_PROFILES_FILE", bad_profiles.c_str(), 1);
  ve::test::ChildProcess monitor({VE_BINARY, "monitor", "--domain", d, "--csv", "--duration", "60"}, tmp + ".csv",
                                 tmp + ".err");
  unsetenv("FASTRTPS_DEFAULT_PROFILES_FILE");
  ASSERT_TRUE(monitor.started());

  // Rows of the publisher arrive (a few thousand), then the monitor is stopped.
  auto rows = [&] {
    const std::string csv = ve::test::read_file(tmp + ".csv");
    std::size_t n = 0;
    for (char c : csv) n += c == '\n';
    return n;
  };
  ASSERT_TRUE(ve::test::wait_until([&] { return rows() > 2000; }, ve::test::patience(30s)))
      << ve::test::read_file(tmp + ".err") << run.log();
  monitor.signal(SIGTERM);
  EXPECT_EQ(monitor.wait_exit(ve::test::patience(15s)), 0) << ve::test::read_file(tmp + ".err");
  run.signal(SIGTERM);
  EXPECT_EQ(run.wait_exit(ve::test::patience(15s)), 0) << run.log();

  const std::string csv = ve::test::read_file(tmp + ".csv");
  const std::string err = ve::test::read_file(tmp + ".err");
  // Fast DDS did complain, and on stderr, through the product's logger.
  EXPECT_NE(err.find("Fast DDS [XMLPARSER]"), std::string::npos) << "no Fast DDS log line on stderr:\n" << err;
  EXPECT_EQ(csv.find("XMLPARSER"), std::string::npos) << "a Fast DDS log line on stdout";

  // stdout: the header, then rows with the header's column count, every cell a number.
  std::istringstream in(csv);
  std::string line;
  ASSERT_TRUE(std::getline(in, line));
  const auto header = split(line);
  ASSERT_EQ(header.size(), 14u) << line;
  EXPECT_EQ(header[0], "axis_id");
  std::size_t data = 0, foreign = 0;
  std::string first_foreign;
  bool last_complete = !csv.empty() && csv.back() == '\n';
  std::vector<std::string> lines;
  while (std::getline(in, line)) lines.push_back(line);
  for (std::size_t i = 0; i < lines.size(); ++i) {
    // The very last line may be cut by the stop only if it has no newline.
    if (i + 1 == lines.size() && !last_complete) break;
    const auto f = split(lines[i]);
    bool ok = f.size() == header.size();
    for (std::size_t k = 0; ok && k < f.size(); ++k) ok = is_number(f[k]);
    if (ok) {
      ++data;
    } else {
      if (foreign++ == 0) first_foreign = lines[i];
    }
  }
  EXPECT_EQ(foreign, 0u) << "lines that are not CSV rows on stdout, the first: '" << first_foreign << "'";
  EXPECT_GT(data, 2000u);
  std::printf("[ figures  ] monitor --csv: %zu rows of %zu columns, %zu foreign line(s); Fast DDS's complaint on "
              "stderr\n",
              data, header.size(), foreign);

  // One state writer for the one axis.
  EXPECT_NE(err.find("1 state writer(s) matched"), std::string::npos) << err;
  EXPECT_EQ(err.find("2 state writer(s) matched"), std::string::npos) << err;
  std::remove(bad_profiles.c_str());
  std::remove((tmp + ".csv").c_str());
  std::remove((tmp + ".err").c_str());
  std::remove((tmp + ".run.log").c_str());
}

}  // namespace
