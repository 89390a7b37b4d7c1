// What `monitor` prints is what it says it prints:
//  - every column of the table and of the CSV, and every status flag, is explained:
//    in `monitor --help`, and (the table's) above the first table of the output;
//  - `monitor --csv | head -n 3` ends cleanly: the monitor sees its stdout closed and
//    exits 0, quietly, instead of dying of SIGPIPE;
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

#include <algorithm>

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

std::vector<std::string> lines_of(const std::string& text) {
  std::vector<std::string> out;
  std::istringstream in(text);
  for (std::string line; std::getline(in, line);) out.push_back(line);
  return out;
}

std::vector<std::string> words(const std::string& line) {
  std::vector<std::string> out;
  std::istringstream in(line);
  for (std::string w; in >> w;) out.push_back(w);
  return out;
}

/// `virtual-encoder monitor --help`, stdout and stderr.
std::string monitor_help(const std::string& tmp) {
  ve::test::ChildProcess help({VE_BINARY, "monitor", "--help"}, tmp + ".help");
  EXPECT_TRUE(help.started());
  EXPECT_EQ(help.wait_exit(ve::test::patience(std::chrono::seconds(15))), 0) << help.log();
  const std::string text = help.log();
  std::remove((tmp + ".help").c_str());
  return text;
}

/// The status flags `monitor` may print (core::status_to_string).
const std::vector<std::string> kStatusFlags = {"VALID",         "CAL",      "HOMED",     "DEGRADED", "FAULT",
                                               "OUT_OF_TRAVEL", "HALL_REJ", "ACC_FAULT", "H0..H7"};

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
  // Every CSV column is explained in `monitor --help`, at the start of one of its lines.
  const std::string help = monitor_help(tmp);
  for (const auto& column : header)
    EXPECT_TRUE(help.find("\n  " + column + " ") != std::string::npos ||
                help.find("\n  " + column + ",") != std::string::npos ||
                help.find(", " + column + " ") != std::string::npos ||
                help.find(", " + column + ",") != std::string::npos)
        << "CSV column '" << column << "' is not explained in monitor --help:\n"
        << help;
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

// The table: a legend above the first table explains every column of its header and
// every status flag, once (stdout is a file here, not a terminal); `monitor --help`
// carries the same legend.
TEST(MonitorOutput, TableHasALegendForEveryColumnAndStatusFlag) {
  const int domain = ve::test::dds_domain();
  const std::string d = std::to_string(domain);
  const std::string machine = std::string(VE_SOURCE_DIR) + "/tests/integration/data/standstill.yaml";
  const std::string tmp = "/tmp/ve_it_monitor_legend_" + std::to_string(getpid());
  ve::test::ChildProcess run({VE_BINARY, "run", "--config", machine, "--domain", d, "--duration", "60"},
                             tmp + ".run.log");
  ASSERT_TRUE(run.started());
  ve::test::ChildProcess monitor({VE_BINARY, "monitor", "--domain", d, "--duration", "60"}, tmp + ".out",
                                 tmp + ".err");
  ASSERT_TRUE(monitor.started());
  // Until a table has a row of the axis (its name and id, "x(1)") from a sample.
  auto has_row = [&] {
    for (const auto& line : lines_of(ve::test::read_file(tmp + ".out")))
      if (line.rfind("x(1) ", 0) == 0 && line.find("waiting") == std::string::npos) return true;
    return false;
  };
  ASSERT_TRUE(ve::test::wait_until(has_row, ve::test::patience(30s)))
      << ve::test::read_file(tmp + ".out") << ve::test::read_file(tmp + ".err") << run.log();
  monitor.signal(SIGTERM);
  EXPECT_EQ(monitor.wait_exit(ve::test::patience(15s)), 0) << ve::test::read_file(tmp + ".err");
  run.signal(SIGTERM);
  EXPECT_EQ(run.wait_exit(ve::test::patience(15s)), 0) << run.log();

  const auto lines = lines_of(ve::test::read_file(tmp + ".out"));
  std::size_t header_at = lines.size();
  for (std::size_t i = 0; i < lines.size() && header_at == lines.size(); ++i)
    if (lines[i].rfind("axis ", 0) == 0) header_at = i;
  ASSERT_LT(header_at, lines.size()) << "no table header";
  std::string legend;
  for (std::size_t i = 0; i < header_at; ++i) legend += lines[i] + "\n";
  const auto columns = words(lines[header_at]);
  ASSERT_GE(columns.size(), 12u) << lines[header_at];
  for (const char* expected : {"dl-miss(r/o)", "innov", "step[us]", "gaps", "status"})
    EXPECT_NE(std::find(columns.begin(), columns.end(), expected), columns.end()) << lines[header_at];

  const std::string help = monitor_help(tmp);
  for (const auto& column : columns) {
    // Explained at the start of a legend line, or after "; " beside a companion column.
    const bool in_legend = legend.find("\n  " + column + " ") != std::string::npos ||
                           legend.find(";  " + column + " ") != std::string::npos;
    EXPECT_TRUE(in_legend) << "column '" << column << "' is not explained above the table:\n" << legend;
    EXPECT_NE(help.find(column), std::string::npos) << "column '" << column << "' is not in monitor --help";
  }
  for (const auto& flag : kStatusFlags) {
    EXPECT_NE(legend.find(flag + " "), std::string::npos) << "status flag " << flag << " not explained:\n" << legend;
    EXPECT_NE(help.find(flag + " "), std::string::npos) << "status flag " << flag << " not in monitor --help";
  }
  // The flags the axis showed are among them; a row printed before the axis' first
  // sample (its description can come first) says "waiting", as the legend explains, and
  // shows no numbers that would read like a position.
  EXPECT_NE(legend.find("'waiting'"), std::string::npos) << legend;
  std::size_t rows = 0;
  for (std::size_t i = header_at + 1; i < lines.size(); ++i) {
    if (lines[i].rfind("x(1) ", 0) != 0) continue;
    const auto cells = words(lines[i]);
    if (cells.back() == "waiting") {
      EXPECT_EQ(cells.at(1), "-") << lines[i];
      EXPECT_EQ(cells.at(3), "-") << lines[i];
      continue;
    }
    ++rows;
    std::istringstream flags(cells.back());
    for (std::string f; std::getline(flags, f, '|');)
      EXPECT_NE(std::find(kStatusFlags.begin(), kStatusFlags.end(), f), kStatusFlags.end()) << lines[i];
  }
  EXPECT_GT(rows, 0u);
  // The legend is printed once into a file, not with every table.
  std::size_t legends = 0;
  for (const auto& line : lines) legends += line.rfind("Table (one row per axis", 0) == 0;
  EXPECT_EQ(legends, 1u);
  std::printf("[ figures  ] monitor: %zu columns and %zu status flags explained; %zu row(s) of the axis\n",
              columns.size(), kStatusFlags.size(), rows);
  std::remove((tmp + ".out").c_str());
  std::remove((tmp + ".err").c_str());
  std::remove((tmp + ".run.log").c_str());
}

// `monitor --csv | head -n 3`: head takes the header and two rows and leaves; the
// monitor's next write finds the pipe closed. It must exit 0 and say nothing about
// it, not die of SIGPIPE (exit status 141 in the shell). The shell runs with SIGPIPE at
// its default action, as in a terminal, whatever the test process does with it.
TEST(MonitorOutput, CsvIntoAReaderThatLeavesEndsQuietlyWithExitZero) {
  const int domain = ve::test::dds_domain();
  const std::string d = std::to_string(domain);
  const std::string machine = std::string(VE_SOURCE_DIR) + "/tests/integration/data/standstill.yaml";
  const std::string tmp = "/tmp/ve_it_monitor_head_" + std::to_string(getpid());
  ve::test::ChildProcess run({VE_BINARY, "run", "--config", machine, "--domain", d, "--duration", "60"},
                             tmp + ".run.log");
  ASSERT_TRUE(run.started());
  ve::test::ChildProcess pipeline(
      {"/bin/bash", "-c",
       "\"$0\" monitor --domain \"$1\" --csv --duration 60 2>\"$2\" | head -n 3; "
       "echo \"monitor-exit=${PIPESTATUS[0]}\" >&2",
       VE_BINARY, d, tmp + ".monitor.err"},
      tmp + ".out", tmp + ".err", [] {
        struct sigaction sa {};
        sa.sa_handler = SIG_DFL;
        sigaction(SIGPIPE, &sa, nullptr);
        sigset_t set;
        sigemptyset(&set);
        sigaddset(&set, SIGPIPE);
        sigprocmask(SIG_UNBLOCK, &set, nullptr);
      });
  ASSERT_TRUE(pipeline.started());
  // It ends by itself once head has its lines: well before the monitor's 60 s.
  EXPECT_EQ(pipeline.wait_exit(ve::test::patience(45s)), 0) << ve::test::read_file(tmp + ".err");
  run.signal(SIGTERM);
  EXPECT_EQ(run.wait_exit(ve::test::patience(15s)), 0) << run.log();

  const auto out = lines_of(ve::test::read_file(tmp + ".out"));
  ASSERT_EQ(out.size(), 3u) << ve::test::read_file(tmp + ".out");
  EXPECT_EQ(out[0].rfind("axis_id,sequence,", 0), 0u) << out[0];
  EXPECT_EQ(out[1].rfind("1,", 0), 0u) << out[1];
  const std::string shell = ve::test::read_file(tmp + ".err");
  const std::string err = ve::test::read_file(tmp + ".monitor.err");
  EXPECT_NE(shell.find("monitor-exit=0"), std::string::npos) << "monitor's exit: " << shell << "\n" << err;
  for (const char* noise : {"Broken pipe", "SIGPIPE", "cannot write"}) {
    EXPECT_EQ(shell.find(noise), std::string::npos) << shell;
    EXPECT_EQ(err.find(noise), std::string::npos) << err;
  }
  std::printf("[ figures  ] monitor --csv | head -n 3: %zu lines, %s\n", out.size(),
              shell.find("monitor-exit=0") != std::string::npos ? "monitor exit 0" : "monitor did not exit 0");
  for (const char* ext : {".out", ".err", ".monitor.err", ".run.log"}) std::remove((tmp + ext).c_str());
}

}  // namespace
