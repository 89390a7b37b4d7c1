// Homing by the magnet signature through the real binary: an axis that starts
// anywhere homes itself on its first move; at a clean shutdown it keeps its
// position, so the next start at rest is homed at once; the kept position is used
// once, and one measured with another calibration, or outside the travel, is
// refused with its reason.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>

#include "process.hpp"
#include "temp_dir.hpp"
#include "test_domain.hpp"

namespace {

using namespace std::chrono_literals;
namespace fs = std::filesystem;
using ve::test::ChildProcess;
using ve::test::read_file;

using ve::test::TempDir;

/// The shipped realistic machine (its calibration matches its simulated track), with
/// signature homing, a state file in `dir` and the given motion profile.
fs::path machine(const fs::path& dir, const std::string& profile) {
  const std::string src = std::string(VE_SOURCE_DIR) + "/config/machines/";
  std::string text = read_file(src + "sim-realistic.yaml");
  auto replace = [&](const std::string& from, const std::string& to) {
    const auto at = text.find(from);
    EXPECT_NE(at, std::string::npos) << from;
    if (at != std::string::npos) text.replace(at, from.size(), to);
  };
  replace("motor: ../motors/", "motor: " + src + "../motors/");
  replace("calibration: ../calibration/", "calibration: " + src + "../calibration/");
  // The profile block: from its key to the imperfections.
  const auto p0 = text.find("      profile:");
  const auto p1 = text.find("      imperfections:");
  EXPECT_TRUE(p0 != std::string::npos && p1 != std::string::npos);
  text.replace(p0, p1 - p0, "      profile: " + profile + "\n");
  const auto h0 = text.find("    homing:");
  EXPECT_NE(h0, std::string::npos);
  text.replace(h0, std::string::npos,
               "    homing: {mode: signature, state_file: " + (dir / "x.kept.yaml").string() + "}\n");
  const fs::path out = dir / "machine.yaml";
  std::ofstream(out) << text;
  return out;
}

std::string run(const fs::path& machine_file, const fs::path& log, double seconds) {
  ChildProcess p({VE_BINARY, "run", "--config", machine_file.string(), "--domain", std::to_string(ve::test::dds_domain()),
                  "--duration", std::to_string(seconds)},
                 log.string());
  EXPECT_TRUE(p.started());
  EXPECT_EQ(p.wait_exit(60s), 0) << p.log();
  return p.log();
}

double kept_position(const fs::path& file) {
  std::smatch m;
  const std::string text = read_file(file);
  if (!std::regex_search(text, m, std::regex("position_m: ([-0-9.e]+)"))) return NAN;
  return std::strtod(m[1].str().c_str(), nullptr);
}

TEST(KeptPosition, HomesOnTheFirstMoveKeepsThePositionAndRestartsHomedAtRest) {
  TempDir dir;
  const fs::path kept = dir.path / "x.kept.yaml";
  // 1. Start at 0.5 m knowing nothing, move 30 mm (2.5 periods), rest there.
  const auto moving = machine(dir.path,
                              "{type: point_to_point, start_m: 0.5, min_m: 0.499, max_m: 0.53, max_velocity_mps: 0.2, "
                              "max_acceleration_mps2: 2, dwell_s: 30}");
  std::string log = run(moving, dir.path / "run1.log", 2.0);
  EXPECT_NE(log.find("no position kept from a clean shutdown"), std::string::npos) << log;
  std::smatch m;
  ASSERT_TRUE(std::regex_search(log, m, std::regex("homed by the magnet signature after ([0-9.]+) mm"))) << log;
  const double motion_mm = std::strtod(m[1].str().c_str(), nullptr);
  std::printf("[ figures  ] homed after %.1f mm of motion\n", motion_mm);
  EXPECT_LE(motion_mm, 24.0);  // two periods
  ASSERT_TRUE(fs::exists(kept)) << log;
  // Where the simulated carriage rests: 0.53 m.
  EXPECT_NEAR(kept_position(kept), 0.53, 5e-6) << read_file(kept);

  // 2. Start again at rest there: homed from the first sample; the file is used once
  //    and written again at this clean shutdown.
  const auto resting = machine(dir.path, "{type: standstill, start_m: 0.53}");
  log = run(resting, dir.path / "run2.log", 1.0);
  EXPECT_NE(log.find("starting homed at 0.53"), std::string::npos) << log;
  EXPECT_NE(log.find("axis 'x': homed\n"), std::string::npos) << log;
  EXPECT_EQ(log.find("not homed"), std::string::npos) << log;
  ASSERT_TRUE(fs::exists(kept));
  EXPECT_NEAR(kept_position(kept), 0.53, 5e-6);

  const std::string good = read_file(kept);

  // 3. A position measured with another calibration is refused, with the reason.
  std::string text = good;
  text = std::regex_replace(text, std::regex("calibration_id: \"[0-9a-f]+\""), "calibration_id: \"0123456789abcdef\"");
  std::ofstream(kept) << text;
  log = run(resting, dir.path / "run3.log", 1.0);
  EXPECT_NE(log.find("kept position not used"), std::string::npos) << log;
  EXPECT_NE(log.find("measured with calibration 0123456789abcdef"), std::string::npos) << log;
  EXPECT_EQ(log.find("axis 'x': homed"), std::string::npos) << log;
  // Never moved, never homed: nothing to keep.
  EXPECT_NE(log.find("not homed at shutdown; no position kept"), std::string::npos) << log;
  EXPECT_FALSE(fs::exists(kept));

  // 4. A position outside the motor's travel is refused naming the file, line and
  //    field, with compact numbers.
  std::ofstream(kept) << std::regex_replace(good, std::regex("position_m: [-0-9.e+]+"), "position_m: 5");
  log = run(resting, dir.path / "run4.log", 1.0);
  EXPECT_NE(log.find("kept position not used"), std::string::npos) << log;
  EXPECT_NE(log.find("x.kept.yaml:"), std::string::npos) << log;
  EXPECT_NE(log.find("position_m: 5 out of range [0, "), std::string::npos) << log;
  EXPECT_EQ(log.find("5.000000"), std::string::npos) << log;
  EXPECT_EQ(log.find("axis 'x': homed"), std::string::npos) << log;
}

}  // namespace
