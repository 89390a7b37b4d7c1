// The kept position (homing.state_file) checked against the motor's travel: a refusal
// names the file, the line and the field, with compact numbers and the unit, and the
// file is removed either way (a position is used once).
#include <gtest/gtest.h>

#include <stdlib.h>

#include <filesystem>
#include <fstream>
#include <string>

#include "config/kept_position.hpp"

namespace {

namespace fs = std::filesystem;
using ve::config::KeptPosition;
using ve::config::KeptRead;
using ve::config::take_kept_position;

class KeptPositionFile : public ::testing::Test {
 protected:
  void SetUp() override {
    std::string tmpl = (fs::temp_directory_path() / "ve-kept-XXXXXX").string();
    ASSERT_NE(mkdtemp(tmpl.data()), nullptr);
    dir_ = tmpl;
  }
  void TearDown() override {
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }
  /// A file as the product writes it, with `position` as the position_m text.
  std::string write(const std::string& position) {
    KeptPosition k;
    k.axis = "x";
    k.motor = "sim-12mm";
    k.calibration_id = "0123456789abcdef";
    k.saved_utc = "2026-11-25T12:00:00Z";
    std::string text = ve::config::format_kept_position(k);
    const auto at = text.find("position_m: ");
    const auto end = text.find('\n', at);
    text.replace(at, end - at, "position_m: " + position);
    const std::string path = (dir_ / "x.kept.yaml").string();
    std::ofstream(path) << text;
    return path;
  }
  KeptRead take(const std::string& path, double travel_m, KeptPosition& out, std::string& why) {
    return take_kept_position(path, "x", "sim-12mm", "0123456789abcdef", out, why, travel_m);
  }
  fs::path dir_;
};

TEST_F(KeptPositionFile, OutsideTheTravelIsRefusedNamingTheFileWithCompactNumbers) {
  struct Case {
    const char* position;
    const char* expected;  // after "<path>:<line>: "
  };
  const Case cases[] = {
      {"1.5", "position_m: 1.5 out of range [0, 1.2] m (the motor's travel)"},
      {"-0.000001", "position_m: -1e-06 out of range [0, 1.2] m (the motor's travel)"},
      {"1.2000001", "position_m: 1.2000001 out of range [0, 1.2] m (the motor's travel)"},
      {"1e300", "position_m: 1e+300 out of range [0, 1.2] m (the motor's travel)"},
  };
  for (const Case& c : cases) {
    const std::string path = write(c.position);
    KeptPosition k;
    std::string why;
    EXPECT_EQ(take(path, 1.2, k, why), KeptRead::refused) << c.position;
    EXPECT_EQ(why.rfind(path + ":", 0), 0u) << "does not start with the file: " << why;
    EXPECT_NE(why.find(c.expected), std::string::npos) << "'" << c.expected << "' not in: " << why;
    EXPECT_EQ(why.find("000000"), std::string::npos) << "a fixed-point number in: " << why;
    EXPECT_FALSE(fs::exists(path)) << "a refused position must not be used again";
  }
}

TEST_F(KeptPositionFile, InsideTheTravelAndAtItsEndsIsUsed) {
  for (const char* position : {"0", "0.53", "1.2"}) {
    const std::string path = write(position);
    KeptPosition k;
    std::string why;
    EXPECT_EQ(take(path, 1.2, k, why), KeptRead::ok) << position << ": " << why;
    EXPECT_DOUBLE_EQ(k.position_m, std::stod(position));
    EXPECT_FALSE(fs::exists(path));
  }
}

TEST_F(KeptPositionFile, NotANumberIsRefusedNamingTheFileAndLine) {
  const std::string path = write(".nan");
  KeptPosition k;
  std::string why;
  EXPECT_EQ(take(path, 1.2, k, why), KeptRead::refused);
  EXPECT_EQ(why.rfind(path + ":", 0), 0u) << why;
  EXPECT_NE(why.find("position_m is not a number"), std::string::npos) << why;
}

}  // namespace
