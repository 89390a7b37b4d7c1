// The calibration report's plots: `calibrate` writes SVG files beside the report,
// the report names them, and each is a well-formed SVG document (parsed with
// tinyxml2, which Fast DDS links) with its lines drawn from finite numbers.
#include <gtest/gtest.h>
#include <tinyxml2.h>

#include <filesystem>
#include <fstream>
#include <iterator>
#include <sstream>

#include "app/reports.hpp"
#include "app/svg_plot.hpp"
#include "config/calibration_file.hpp"
#include "config/loader.hpp"
#include "core/identification.hpp"
#include "process.hpp"
#include "temp_dir.hpp"
#include "sim/calibration_run.hpp"

namespace {

using namespace std::chrono_literals;
namespace fs = std::filesystem;

using ve::test::TempDir;

void write(const fs::path& p, const std::string& text) { std::ofstream(p) << text; }

std::string read(const fs::path& p) {
  std::ifstream in(p);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

/// A sim machine on a short (0.1 m) copy of the sim-12mm motor with a realistic track.
fs::path make_machine(const fs::path& dir) {
  std::string m = read(std::string(VE_SOURCE_DIR) + "/config/motors/sim-12mm.yaml");
  m.replace(m.find("motor: sim-12mm"), 15, "motor: short-12");
  m.replace(m.find("travel_m: 1.0"), 13, "travel_m: 0.1");
  write(dir / "short.yaml", m);
  const fs::path machine = dir / "machine.yaml";
  write(machine,
        "axes:\n"
        "  - name: x\n"
        "    motor: short.yaml\n"
        "    driver:\n"
        "      type: sim\n"
        "      profile: {type: shuttle, start_m: 0.05, min_m: 0.01, max_m: 0.09}\n"
        "      imperfections: {track_seed: 7, magnet_strength_std: 0.015, magnet_placement_std_m: 20.0e-6,\n"
        "                      sensor_placement_std_m: 50.0e-6, sensor_gain_std: 0.03, sensor_offset_std_v: 0.02,\n"
        "                      hall_delay_s: 20.0e-6, coil_field_v_per_mps2: 0.001, accel_bias_mps2: 0.05,\n"
        "                      accel_delay_s: 250.0e-6}\n"
        "    homing: {mode: startup_position, position_m: 0.05}\n");
  return machine;
}

/// Parses an SVG file; checks the root, that lines are drawn, and that no number is NaN or infinite.
void expect_well_formed_svg(const fs::path& path) {
  SCOPED_TRACE(path.string());
  ASSERT_TRUE(fs::exists(path));
  tinyxml2::XMLDocument doc;
  ASSERT_EQ(doc.LoadFile(path.c_str()), tinyxml2::XML_SUCCESS) << doc.ErrorStr();
  const tinyxml2::XMLElement* root = doc.RootElement();
  ASSERT_NE(root, nullptr);
  EXPECT_STREQ(root->Name(), "svg");
  EXPECT_STREQ(root->Attribute("xmlns"), "http://www.w3.org/2000/svg");
  EXPECT_GT(root->IntAttribute("width"), 0);
  EXPECT_GT(root->IntAttribute("height"), 0);
  int polylines = 0;
  std::vector<const tinyxml2::XMLElement*> stack{root};
  while (!stack.empty()) {
    const auto* e = stack.back();
    stack.pop_back();
    if (std::string(e->Name()) == "polyline") {
      ++polylines;
      const char* pts = e->Attribute("points");
      ASSERT_NE(pts, nullptr);
      const std::string p(pts);
      EXPECT_FALSE(p.empty());
      EXPECT_EQ(p.find("nan"), std::string::npos);
      EXPECT_EQ(p.find("inf"), std::string::npos);
    }
    for (const auto* c = e->FirstChildElement(); c != nullptr; c = c->NextSiblingElement()) stack.push_back(c);
  }
  EXPECT_GT(polylines, 0);
}

const char* kPlots[] = {"table-period", "table-all-periods", "residuals", "forward-backward"};

TEST(CalibrationReport, PlotsAreWellFormedSvgAndNamedInTheReport) {
  TempDir dir;
  const auto loaded = ve::config::load_machine_file(make_machine(dir.path).string());
  ASSERT_TRUE(loaded.ok()) << ve::config::to_string(loaded.errors);
  const auto& axis = loaded.config.axes.at(0);
  std::vector<ve::core::ReferenceSegment> segments;
  std::string error;
  ASSERT_TRUE(ve::sim::record_calibration_run(axis.motor, axis.driver.sim, {}, segments, error)) << error;
  ve::core::Calibration cal;
  ve::core::IdentificationReport report;
  ASSERT_TRUE(ve::core::identify_with_reference(axis.motor, segments, {}, cal, report, error)) << error;
  cal.info.id = "0123456789abcdef";

  // The curves cover the travel, with data in most bins.
  const auto& c = report.curves;
  ASSERT_EQ(c.position_m.size(), c.residual_mv.size());
  ASSERT_EQ(c.position_m.size(), c.forward_backward_um.size());
  int finite_fb = 0, finite_res = 0;
  for (std::size_t i = 0; i < c.position_m.size(); ++i) {
    finite_fb += std::isfinite(c.forward_backward_um[i]);
    finite_res += std::isfinite(c.residual_mv[i]);
  }
  EXPECT_GT(finite_fb, static_cast<int>(0.8 * c.position_m.size()));
  EXPECT_GT(finite_res, static_cast<int>(0.8 * c.position_m.size()));

  const std::string base = (dir.path / "x.cal.yaml").string();
  const auto written = ve::app::write_calibration_plots(base, cal, report, error);
  EXPECT_TRUE(error.empty()) << error;
  ASSERT_EQ(written.size(), 4u);
  for (const char* name : kPlots) expect_well_formed_svg(base + "." + name + ".svg");
  const std::string text = ve::app::format_identification_report(axis, cal, report, written);
  for (const char* name : kPlots)
    EXPECT_NE(text.find(std::string("x.cal.yaml.") + name + ".svg"), std::string::npos) << text;
}

TEST(CalibrationReport, SvgEscapesTextAndSurvivesEmptyAndNanSeries) {
  ve::app::SvgPlot p;
  p.title = "a < b & \"c\"";
  p.series.push_back({"nan only", "#000000", {0.0, 1.0}, {std::nan(""), std::nan("")}, 1.0, 1.0});
  p.series.push_back({"", "#000000", {}, {}, 1.0, 1.0});
  p.series.push_back({"broken", "#000000", {0.0, 1.0, 2.0, 3.0}, {1.0, std::nan(""), 2.0, 3.0}, 1.0, 1.0});
  TempDir dir;
  write(dir.path / "p.svg", ve::app::render_svg(p));
  expect_well_formed_svg(dir.path / "p.svg");
  tinyxml2::XMLDocument doc;
  ASSERT_EQ(doc.LoadFile((dir.path / "p.svg").c_str()), tinyxml2::XML_SUCCESS);
  EXPECT_STREQ(doc.RootElement()->FirstChildElement("title")->GetText(), "a < b & \"c\"");
}

TEST(CalibrationReport, CalibrateCommandWritesThePlotsBesideTheReport) {
  TempDir dir;
  const fs::path machine = make_machine(dir.path);
  const fs::path cal = dir.path / "out" / "x.cal.yaml";
  ve::test::ChildProcess p({VE_BINARY, "calibrate", "--config", machine.string(), "--out", cal.string(), "--force"},
                           (dir.path / "cal.log").string());
  ASSERT_EQ(p.wait_exit(120s), 0) << p.log();
  const std::string report = read(cal.string() + ".report.txt");
  for (const char* name : kPlots) {
    const std::string file = std::string("x.cal.yaml.") + name + ".svg";
    EXPECT_NE(report.find(file), std::string::npos) << report;
    expect_well_formed_svg(dir.path / "out" / file);
  }
}

// calibrate --thermal adds each Hall sensor's temperature coefficients to the axis'
// calibration, from a calibration run of the simulator 15 K warmer: the file stays
// loadable, keeps its table and gains a thermal section. A run too close in
// temperature, or no calibration to add them to, is refused and changes nothing.
TEST(CalibrationReport, ThermalCalibrationAddsTheCoefficientsAndRefusesWhatCannotGiveThem) {
  TempDir dir;
  const fs::path machine = make_machine(dir.path);
  const fs::path cal = dir.path / "out" / "x.cal.yaml";
  {
    ve::test::ChildProcess p({VE_BINARY, "calibrate", "--config", machine.string(), "--out", cal.string(), "--thermal"},
                             (dir.path / "none.log").string());
    EXPECT_EQ(p.wait_exit(120s), 2) << p.log();
    EXPECT_NE(p.log().find("thermal calibration needs the axis' calibration first"), std::string::npos) << p.log();
    EXPECT_FALSE(fs::exists(cal));
  }
  {
    ve::test::ChildProcess p({VE_BINARY, "calibrate", "--config", machine.string(), "--out", cal.string(), "--force"},
                             (dir.path / "cal.log").string());
    ASSERT_EQ(p.wait_exit(120s), 0) << p.log();
  }
  const std::string plain = read(cal);
  EXPECT_EQ(plain.find("\nthermal:"), std::string::npos);
  {
    ve::test::ChildProcess p({VE_BINARY, "calibrate", "--config", machine.string(), "--out", cal.string(), "--thermal",
                              "--sim-temperature-rise", "2"},
                             (dir.path / "close.log").string());
    EXPECT_EQ(p.wait_exit(120s), 1) << p.log();
    EXPECT_NE(p.log().find("record it at least 5 K warmer or colder"), std::string::npos) << p.log();
    EXPECT_EQ(read(cal), plain) << "a refused thermal calibration changed the file";
  }
  {
    ve::test::ChildProcess p({VE_BINARY, "calibrate", "--config", machine.string(), "--out", cal.string(), "--thermal"},
                             (dir.path / "thermal.log").string());
    ASSERT_EQ(p.wait_exit(120s), 0) << p.log();
    EXPECT_NE(p.log().find("sensor 3: offset"), std::string::npos) << p.log();
  }
  const std::string thermal = read(cal);
  ASSERT_NE(thermal.find("\nthermal:"), std::string::npos) << thermal.substr(0, 2000);
  // The table is the calibration's, untouched.
  EXPECT_EQ(thermal.substr(thermal.find("\ntable:")), plain.substr(plain.find("\ntable:")));
  EXPECT_TRUE(fs::exists(cal.string() + ".thermal.txt"));
  {
    // The summary names the axis and the motor and says where the rise came from.
    std::ifstream in(cal.string() + ".thermal.txt");
    const std::string summary((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    EXPECT_NE(summary.find("thermal calibration of axis '"), std::string::npos) << summary;
    EXPECT_NE(summary.find("K from the calibration (read from the sensors' common gain)"), std::string::npos)
        << summary;
  }
  const auto loaded = ve::config::load_machine_file(machine.string());
  ASSERT_TRUE(loaded.ok()) << ve::config::to_string(loaded.errors);
  const auto back = ve::config::load_calibration_file(cal.string(), loaded.config.axes.at(0).motor);
  ASSERT_TRUE(back.ok()) << ve::config::to_string(back.errors);
  EXPECT_TRUE(back.calibration.model.thermal_known);
  EXPECT_NEAR(back.calibration.model.thermal_rise_k, 15.0, 2.0);
}

}  // namespace
