// A calibration killed at any moment, also while it writes its file, leaves a
// usable calibration behind: the previous file byte for byte, or the complete new
// one. The real `virtual-encoder calibrate`, killed with SIGKILL (no handler runs).
#include <gtest/gtest.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>
#include <thread>

#include "config/calibration_file.hpp"
#include "config/loader.hpp"
#include "process.hpp"
#include "temp_dir.hpp"

namespace {

using namespace std::chrono_literals;
namespace fs = std::filesystem;
using ve::test::ChildProcess;

using ve::test::TempDir;

TEST(CalibrationKill, KilledAtAnyMomentLeavesTheOldOrTheNewFileNeverABrokenOne) {
  TempDir dir;
  const fs::path machine = dir.path / "machine.yaml";
  std::ofstream(machine) << "machine: kill-test\n"
                            "axes:\n"
                            "  - name: x\n"
                            "    motor: " << VE_SOURCE_DIR << "/config/motors/sim-12mm.yaml\n"
                            "    driver: {type: sim}\n";
  const fs::path cal = dir.path / "x.cal.yaml";
  auto args = [&](const char* speed, const fs::path& out) {
    return std::vector<std::string>{VE_BINARY, "calibrate", "--config", machine.string(), "--out", out.string(),
                                    "--speed", speed};
  };

  // The previous calibration.
  {
    ChildProcess first(args("0.05", cal), (dir.path / "first.log").string());
    ASSERT_EQ(first.wait_exit(300s), 0) << first.log();
  }
  // How long a whole new calibration takes here (into another file).
  const auto t0 = std::chrono::steady_clock::now();
  {
    ChildProcess timing(args("0.02", dir.path / "timing.cal.yaml"), (dir.path / "timing.log").string());
    ASSERT_EQ(timing.wait_exit(300s), 0) << timing.log();
  }
  const auto whole = std::chrono::steady_clock::now() - t0;
  const auto motor = ve::config::load_machine_file(machine.string());
  ASSERT_TRUE(motor.ok()) << ve::config::to_string(motor.errors);
  const auto& expected = motor.config.axes[0].motor;
  const std::string old_text = ve::test::read_file(cal.string());
  const auto old_load = ve::config::load_calibration_file(cal.string(), expected);
  ASSERT_TRUE(old_load.ok());

  // Kill new calibrations (another speed: another table, another id) ever later,
  // the last ones around the end, where the file is written.
  int kept_old = 0, complete_new = 0;
  std::set<std::string> ids;
  const int kills = 12;
  for (int i = 0; i < kills; ++i) {
    const double fraction = 0.5 + 0.6 * i / (kills - 1);  // 50 % .. 110 % of a whole run
    const auto at = std::chrono::duration_cast<std::chrono::milliseconds>(whole * fraction);
    ChildProcess p(args("0.02", cal), (dir.path / ("kill" + std::to_string(i) + ".log")).string());
    ASSERT_TRUE(p.started());
    std::this_thread::sleep_for(at);
    p.signal(SIGKILL);
    p.wait_exit(30s);

    ASSERT_TRUE(fs::exists(cal)) << "kill " << i << " at " << at.count() << " ms removed the calibration";
    const std::string text = ve::test::read_file(cal.string());
    const auto load = ve::config::load_calibration_file(cal.string(), expected);
    ASSERT_TRUE(load.ok()) << "kill " << i << " at " << at.count() << " ms left a broken file: "
                           << ve::config::to_string(load.errors);
    if (text == old_text) {
      ++kept_old;
    } else {
      EXPECT_NE(load.calibration.info.id, old_load.calibration.info.id);
      ++complete_new;
    }
    ids.insert(load.calibration.info.id);
  }
  std::printf("[ figures  ] a whole calibration took %.2f s; %d kills left the old file, %d a complete new one\n",
              std::chrono::duration<double>(whole).count(), kept_old, complete_new);
  // Killed halfway, the old file is what remains.
  EXPECT_GT(kept_old, 0);
  EXPECT_LE(ids.size(), 2u);  // the old calibration, or the one new one
}

}  // namespace
