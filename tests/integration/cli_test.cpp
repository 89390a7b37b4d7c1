// The command line as a user meets it: `check` on a broken machine file,
// `calibrate` -> `check` -> `run` with the calibration it wrote, refusal of a
// damaged calibration, and the default (embedded) machine.
#include <gtest/gtest.h>

#include <fcntl.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <sstream>

#include "app/dds_io.hpp"
#include "config/calibration_file.hpp"
#include "config/loader.hpp"
#include "replay/raw_log.hpp"
#include "sim/calibration_run.hpp"
#include "core/status.hpp"
#include "process.hpp"
#include "speed.hpp"
#include "temp_dir.hpp"
#include "test_domain.hpp"

namespace {

using namespace std::chrono_literals;
namespace fs = std::filesystem;
using ve::test::ChildProcess;
using ve::test::wait_until;

using ve::test::TempDir;

void write(const fs::path& p, const std::string& text) {
  std::ofstream out(p);
  out << text;
}

std::string motor_path() { return std::string(VE_SOURCE_DIR) + "/config/motors/sim-12mm.yaml"; }

/// Runs the binary to completion; returns the exit code and fills `output`.
int run_cli(const std::vector<std::string>& args, std::string& output, const fs::path& log) {
  std::vector<std::string> argv{VE_BINARY};
  argv.insert(argv.end(), args.begin(), args.end());
  ChildProcess p(argv, log.string());
  const int code = p.wait_exit(120s);
  output = p.log();
  return code;
}

TEST(Cli, CheckReportsEveryProblemWithFileLineColumnAndFails) {
  TempDir dir;
  const fs::path machine = dir.path / "bad.yaml";
  write(machine,
        "machine: broken\n"                        // 1
        "dds:\n"                                   // 2
        "  domain: 7\n"                            // 3
        "axes:\n"                                  // 4
        "  - name: x\n"                            // 5
        "    motor: " + motor_path() + "\n"        // 6
        "    drivr: {type: sim}\n"                 // 7
        "    output: {direction: 2}\n");           // 8
  std::string out;
  EXPECT_EQ(run_cli({"check", "--config", machine.string()}, out, dir.path / "check.log"), 1) << out;
  EXPECT_NE(out.find(machine.string() + ":7:5: axes[0].drivr"), std::string::npos) << out;
  EXPECT_NE(out.find(machine.string() + ":8:25: axes[0].output.direction"), std::string::npos) << out;
  EXPECT_NE(out.find("2 problem(s)"), std::string::npos) << out;
}

TEST(Cli, CheckAcceptsTheEmbeddedDefault) {
  TempDir dir;
  std::string out;
  EXPECT_EQ(run_cli({"check"}, out, dir.path / "check.log"), 0) << out;
  EXPECT_NE(out.find("OK: machine 'sim-single-axis'"), std::string::npos) << out;
}

TEST(Cli, CalibrateThenCheckThenRunPublishesCalibratedPositions) {
  TempDir dir;
  const fs::path machine = dir.path / "machine.yaml";
  write(machine,
        "machine: calibrated\n"
        "axes:\n"
        "  - name: x\n"
        "    motor: " + motor_path() + "\n"
        "    calibration: cal/x.cal.yaml\n"
        "    driver:\n"
        "      type: sim\n"
        "      profile: {type: standstill, start_m: 0.6123}\n"
        "    homing: {mode: startup_position, position_m: 0.61}\n");

  std::string out;
  // Before calibrating, check names the missing file.
  EXPECT_EQ(run_cli({"check", "--config", machine.string()}, out, dir.path / "c0.log"), 1) << out;
  EXPECT_NE(out.find("x.cal.yaml"), std::string::npos) << out;

  ASSERT_EQ(run_cli({"calibrate", "--config", machine.string()}, out, dir.path / "cal.log"), 0) << out;
  ASSERT_TRUE(fs::exists(dir.path / "cal" / "x.cal.yaml")) << out;
  EXPECT_EQ(run_cli({"check", "--config", machine.string()}, out, dir.path / "c1.log"), 0) << out;
  EXPECT_NE(out.find("calibration "), std::string::npos) << out;

  // The run publishes CALIBRATED samples at the right place.
  const int domain = ve::test::dds_domain();
  ve::app::DdsOptions o;
  o.domain = domain;
  std::string error;
  auto ctx = ve::app::DdsContext::create(o, error);
  ASSERT_TRUE(ctx) << error;
  std::mutex m;
  std::vector<ve::dds::EncoderState> got;
  got.reserve(100000);
  {
    ve::app::StateReader reader(*ctx, 0.0, [&](const ve::dds::EncoderState& s) {
      std::lock_guard<std::mutex> lock(m);
      got.push_back(s);
    });
    ChildProcess run({VE_BINARY, "run", "--config", machine.string(), "--domain", std::to_string(domain), "--duration",
                      "1.5", "--wait-for-subscriber", "10"},
                     (dir.path / "run.log").string());
    EXPECT_EQ(run.wait_exit(30s), 0) << run.log();
  }
  ctx.reset();
  double sum_sq = 0;
  int n = 0;
  for (const auto& s : got) {
    if (s.sequence_number() < 400) continue;
    EXPECT_TRUE(s.status() & ve::core::status::kCalibrated) << ve::core::status_to_string(s.status());
    EXPECT_TRUE(s.status() & ve::core::status::kValid) << ve::core::status_to_string(s.status());
    sum_sq += (s.position_m() - 0.6123) * (s.position_m() - 0.6123);
    ++n;
  }
  ASSERT_GT(n, 1000);
  const double rms_um = std::sqrt(sum_sq / n) * 1e6;
  std::printf("[ figures  ] standstill on the calibrated table via DDS: %.3f um RMS over %d samples\n", rms_um, n);
  EXPECT_LT(rms_um, 5.0);

  // A damaged calibration is refused by check and by run, and named.
  {
    std::fstream f(dir.path / "cal" / "x.cal.yaml", std::ios::in | std::ios::out);
    f.seekp(-40, std::ios::end);
    f << "9";
  }
  EXPECT_EQ(run_cli({"check", "--config", machine.string()}, out, dir.path / "c2.log"), 1) << out;
  EXPECT_NE(out.find("x.cal.yaml"), std::string::npos) << out;
  EXPECT_NE(run_cli({"run", "--config", machine.string(), "--duration", "1"}, out, dir.path / "r2.log"), 0) << out;
}

}  // namespace

namespace {

// `monitor --csv > file` is how a commissioning engineer records a run for plotting:
// stdout must be the CSV stream and nothing else, the log goes to stderr.
TEST(Cli, MonitorCsvStdoutIsOnlyCsvTheLogGoesToStderr) {
  TempDir dir;
  const int domain = ve::test::dds_domain();
  const std::string standstill = std::string(VE_SOURCE_DIR) + "/tests/integration/data/standstill.yaml";
  ChildProcess run({VE_BINARY, "run", "--config", standstill, "--domain", std::to_string(domain), "--duration", "60"},
                   (dir.path / "run.log").string());
  ASSERT_TRUE(run.started());
  const fs::path out = dir.path / "monitor.csv", err = dir.path / "monitor.err";
  ChildProcess monitor({VE_BINARY, "monitor", "--csv", "--domain", std::to_string(domain), "--duration", "60"},
                       out.string(), err.string());
  ASSERT_TRUE(monitor.started());
  auto rows = [&] {
    std::size_t n = 0;
    std::istringstream in(ve::test::read_file(out.string()));
    for (std::string line; std::getline(in, line);) n += line.rfind("1,", 0) == 0;
    return n;
  };
  ASSERT_TRUE(wait_until([&] { return rows() > 2000; }, 30s)) << ve::test::read_file(err.string()) << run.log();
  monitor.signal(SIGINT);
  EXPECT_EQ(monitor.wait_exit(20s), 0) << ve::test::read_file(err.string());
  run.signal(SIGINT);
  EXPECT_EQ(run.wait_exit(20s), 0) << run.log();

  // stdout: the header, then rows of 14 fields, nothing else.
  std::istringstream csv(ve::test::read_file(out.string()));
  std::string line;
  ASSERT_TRUE(std::getline(csv, line));
  EXPECT_EQ(line.rfind("axis_id,sequence,", 0), 0u) << line;
  std::size_t n = 0;
  while (std::getline(csv, line)) {
    ASSERT_EQ(std::count(line.begin(), line.end(), ','), 13) << "not a CSV row on stdout: " << line;
    ASSERT_EQ(line.rfind("1,", 0), 0u) << line;
    ++n;
  }
  EXPECT_GT(n, 2000u);
  // stderr: the log, here the monitor saying it matched the encoder's writer.
  const std::string log = ve::test::read_file(err.string());
  EXPECT_NE(log.find("state writer(s) matched"), std::string::npos) << log;
  EXPECT_EQ(log.find("axis_id,"), std::string::npos) << log;
}

TEST(Cli, CalibrateFromARecordedLogWithReference) {
  TempDir dir;
  // A short motor keeps the sweep (and the log) small.
  std::ifstream in(motor_path());
  std::stringstream motor_text;
  motor_text << in.rdbuf();
  std::string m = motor_text.str();
  m.replace(m.find("motor: sim-12mm"), 15, "motor: short-12");
  m.replace(m.find("travel_m: 1.0"), 13, "travel_m: 0.1");
  write(dir.path / "short.yaml", m);
  const fs::path machine = dir.path / "machine.yaml";
  write(machine,
        "axes:\n"
        "  - name: x\n"
        "    motor: short.yaml\n"
        "    driver:\n"
        "      type: sim\n"
        "      profile: {type: standstill, start_m: 0.05, min_m: 0.005, max_m: 0.095}\n"
        "      imperfections: {hall_delay_s: 20.0e-6, coil_field_v_per_mps2: 0.001, accel_bias_mps2: 0.05,\n"
        "                      accel_delay_s: 250.0e-6, magnet_placement_std_m: 20.0e-6}\n"
        "    homing: {mode: startup_position, position_m: 0.05}\n");
  auto loaded = ve::config::load_machine_file(machine.string());
  ASSERT_TRUE(loaded.ok()) << ve::config::to_string(loaded.errors);
  const auto& axis = loaded.config.axes.at(0);

  // The calibration motion, recorded as a commissioning engineer would: one log
  // with the ruler's position, the two parts of the motion a second apart.
  std::vector<ve::core::ReferenceSegment> segments;
  std::string error;
  ASSERT_TRUE(ve::sim::record_calibration_run(axis.motor, axis.driver.sim, {}, segments, error)) << error;
  const fs::path log = dir.path / "calibration.csv";
  {
    ve::replay::RawLogWriter w;
    ve::replay::RawLogWriter::Columns cols;
    cols.hall_count = 4;
    cols.reference = true;
    ASSERT_TRUE(w.open(log.string(), cols, {{"sample_rate_hz", "4000"}}, error)) << error;
    std::int64_t offset = 0;
    for (const auto& seg : segments) {
      const std::int64_t base = offset - seg.samples.front().t_ns;
      for (std::size_t i = 0; i < seg.samples.size(); ++i) {
        ve::core::RawSample s = seg.samples[i];
        s.t_ns += base;
        ASSERT_TRUE(w.write(s, nullptr, &seg.reference_m[i])) << w.error();
      }
      offset += seg.samples.back().t_ns - seg.samples.front().t_ns + 1000000000LL;
    }
    ASSERT_TRUE(w.close(error)) << error;
  }

  std::string out;
  const fs::path cal = dir.path / "x.cal.yaml";
  ASSERT_EQ(run_cli({"calibrate", "--config", machine.string(), "--log", log.string(), "--out", cal.string()}, out,
                    dir.path / "cal.log"),
            0)
      << out;
  EXPECT_NE(out.find("Verdict: GOOD"), std::string::npos) << out;
  auto loaded_cal = ve::config::load_calibration_file(cal.string(), axis.motor);
  ASSERT_TRUE(loaded_cal.ok()) << ve::config::to_string(loaded_cal.errors);
  const auto& model = loaded_cal.calibration.model;
  EXPECT_NEAR(model.hall_delay_s, 20e-6, 1e-6);
  EXPECT_NEAR(model.coil_field_v_per_mps2, 0.001, 5e-5);
  EXPECT_NEAR(model.accel_bias_mps2, 0.05, 3e-3);
  EXPECT_NEAR(model.accel_delay_s, 250e-6, 20e-6);

  // A log without a reference column is refused with the reason.
  const fs::path no_ref = dir.path / "no_ref.csv";
  write(no_ref, "# virtual-encoder raw log v1\nt_s,hall_0_v,hall_1_v,hall_2_v,hall_3_v,accel_mps2\n0,1,2,3,4,0\n");
  EXPECT_EQ(run_cli({"calibrate", "--config", machine.string(), "--log", no_ref.string(), "--out", cal.string()}, out,
                    dir.path / "cal2.log"),
            2);
  EXPECT_NE(out.find("ref_position_m"), std::string::npos) << out;
  // ... and the calibration written before is untouched.
  EXPECT_TRUE(ve::config::load_calibration_file(cal.string(), axis.motor).ok());
}

}  // namespace

namespace {

TEST(Cli, RunEndsSoonAfterItsReplayedLogWhateverTheStatusPeriod) {
  TempDir dir;
  std::string out;
  // A short recording of the built-in simulator, replayed as fast as it can be read.
  const fs::path log = dir.path / "short.csv";
  ASSERT_EQ(run_cli({"record", "--out", log.string(), "--duration", "0.3"}, out, dir.path / "record.log"), 0) << out;
  const fs::path machine = dir.path / "replay.yaml";
  write(machine, "axes:\n  - name: x\n    motor: " + motor_path() + "\n    driver: {type: replay, log: " + log.string() +
                     "}\n");
  // With a status line only once a day, the end of the log must still end the run
  // (it used to wait for the next status line).
  std::vector<std::string> argv{VE_BINARY, "run", "--config", machine.string(), "--domain",
                                std::to_string(ve::test::dds_domain()), "--status-period", "86400"};
  ChildProcess p(argv, (dir.path / "run.log").string());
  ASSERT_TRUE(p.started());
  EXPECT_EQ(p.wait_exit(ve::test::patience(60s)), 0) << p.log();
  EXPECT_NE(p.log().find("all sources ended"), std::string::npos) << p.log();
}

}  // namespace
