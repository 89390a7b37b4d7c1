// `evaluate` on logs as real recordings are: with a reference ruler but no truth,
// and with neither. The simulator's recording has both; the tests take columns
// away (and spoil the ruler: an offset, a coarse resolution, missing readings)
// and compare with what the truth says on the same log.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <initializer_list>
#include <sstream>
#include <string>
#include <vector>

#include "process.hpp"
#include "temp_dir.hpp"

namespace {

using namespace std::chrono_literals;
namespace fs = std::filesystem;
using ve::test::ChildProcess;
using ve::test::TempDir;

struct Result {
  int code = -1;
  std::string out;  ///< stdout
  std::string err;  ///< stderr
};

/// Runs the binary to completion, stdout and stderr apart.
Result run_ve(const std::vector<std::string>& args, const fs::path& dir) {
  std::vector<std::string> argv{VE_BINARY};
  argv.insert(argv.end(), args.begin(), args.end());
  const fs::path out = dir / "stdout.txt", err = dir / "stderr.txt";
  Result r;
  {
    ChildProcess p(argv, out.string(), err.string());
    r.code = p.wait_exit(120s);
  }
  r.out = ve::test::read_file(out.string());
  r.err = ve::test::read_file(err.string());
  return r;
}

/// A number in flat JSON text: each key is searched after the previous one, so
/// {"position_um", "rms"} is position_um's rms. NaN when a key is missing.
double json_number(const std::string& json, std::initializer_list<const char*> keys) {
  std::size_t at = 0;
  for (const char* key : keys) {
    at = json.find(std::string("\"") + key + "\":", at);
    if (at == std::string::npos) return std::nan("");
    at += std::string(key).size() + 3;
  }
  return std::strtod(json.c_str() + at, nullptr);
}

/// A simulator recording with truth and ruler columns.
fs::path record(const fs::path& dir, double seconds = 3.0) {
  const fs::path log = dir / "sim.csv";
  const Result r = run_ve({"record", "--fast", "--duration", std::to_string(seconds), "--out", log.string()}, dir);
  EXPECT_EQ(r.code, 0) << r.out << r.err;
  return log;
}

std::vector<std::string> split(const std::string& line) {
  std::vector<std::string> cells;
  std::stringstream s(line);
  std::string cell;
  while (std::getline(s, cell, ',')) cells.push_back(cell);
  if (!line.empty() && line.back() == ',') cells.emplace_back();
  return cells;
}

/// Copies a raw log without the columns `drop`; `ref` (row index, cell) may rewrite
/// each row's ref_position_m cell.
fs::path rewrite(const fs::path& in, const fs::path& out, const std::vector<std::string>& drop,
                 const std::function<void(std::size_t, std::string&)>& ref = nullptr) {
  std::ifstream src(in);
  std::ofstream dst(out);
  std::string line;
  std::vector<bool> keep;
  int ref_col = -1;
  std::size_t row = 0;
  while (std::getline(src, line)) {
    if (line.empty() || line[0] == '#') {
      dst << line << '\n';
      continue;
    }
    auto cells = split(line);
    if (keep.empty()) {  // the header
      for (std::size_t i = 0; i < cells.size(); ++i) {
        keep.push_back(std::find(drop.begin(), drop.end(), cells[i]) == drop.end());
        if (cells[i] == "ref_position_m") ref_col = static_cast<int>(i);
      }
    } else if (ref && ref_col >= 0) {
      ref(row++, cells[static_cast<std::size_t>(ref_col)]);
    }
    const char* sep = "";
    for (std::size_t i = 0; i < cells.size(); ++i) {
      if (!keep[i]) continue;
      dst << sep << cells[i];
      sep = ",";
    }
    dst << '\n';
  }
  return out;
}

const std::vector<std::string> kTruth{"true_position_m", "true_velocity_mps", "true_acceleration_mps2"};
const std::vector<std::string> kTruthAndRuler{"true_position_m", "true_velocity_mps", "true_acceleration_mps2",
                                              "ref_position_m"};

std::string fixed9(double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.9f", v);
  return buf;
}

TEST(EvaluateReal, AgainstTheRulerTheScoreIsTheTruthsOnTheSameLog) {
  TempDir dir;
  const fs::path sim = record(dir.path);
  const Result truth = run_ve({"evaluate", "--log", sim.string(), "--json"}, dir.path);
  ASSERT_EQ(truth.code, 0) << truth.err;
  // The truth report keeps its keys and says what it is based on.
  EXPECT_NE(truth.out.find("\"basis\": \"truth\""), std::string::npos) << truth.out;
  for (const char* key : {"position_um", "velocity_mmps", "coverage_2sigma", "not_valid", "window_s", "evaluated"})
    EXPECT_NE(truth.out.find(std::string("\"") + key + "\""), std::string::npos) << key;
  EXPECT_EQ(truth.out.find("\"ruler\""), std::string::npos);

  const fs::path ruler_log = rewrite(sim, dir.path / "ruler.csv", kTruth);
  const Result ruler = run_ve({"evaluate", "--log", ruler_log.string(), "--json"}, dir.path);
  ASSERT_EQ(ruler.code, 0) << ruler.err;
  EXPECT_NE(ruler.out.find("\"basis\": \"ruler\""), std::string::npos) << ruler.out;
  const double truth_rms = json_number(truth.out, {"position_um", "rms"});
  const double ruler_rms = json_number(ruler.out, {"position_um", "rms"});
  const double resolution_um = json_number(ruler.out, {"ruler", "resolution_um"});
  ASSERT_GT(truth_rms, 0.0);
  EXPECT_GT(resolution_um, 0.0);
  EXPECT_LT(resolution_um, 0.1);  // the simulator's ruler is its exact position, written to 1 nm
  EXPECT_NEAR(ruler_rms, truth_rms, 0.1 + resolution_um) << ruler.out;
  const double coverage = json_number(ruler.out, {"coverage_2sigma", "position"});
  EXPECT_GT(coverage, 0.8);
  EXPECT_LE(coverage, 1.0);
  EXPECT_GT(json_number(ruler.out, {"coverage_2sigma", "velocity"}), 0.0);
  EXPECT_NEAR(json_number(ruler.out, {"position_um", "bias"}), 0.0, 1e-6);  // auto offset
  EXPECT_EQ(json_number(ruler.out, {"ruler", "sg_half_window"}), 10.0);
  EXPECT_GE(json_number(ruler.out, {"ruler", "velocity_noise_floor_mmps"}), 0.0);
  EXPECT_GE(json_number(ruler.out, {"ruler", "velocity_curvature_error_mmps"}), 0.0);
  // Velocity against the differentiated ruler: near the truth's, once the start-up
  // transient (the first sample) is out of both.
  const double ruler_v = json_number(ruler.out, {"velocity_mmps", "rms"});
  EXPECT_GT(ruler_v, 0.0);
  EXPECT_LT(ruler_v, 1.0) << ruler.out;

  const Result text = run_ve({"evaluate", "--log", ruler_log.string()}, dir.path);
  ASSERT_EQ(text.code, 0) << text.err;
  EXPECT_NE(text.out.find("against a reference ruler"), std::string::npos) << text.out;
  EXPECT_NE(text.out.find("(estimated"), std::string::npos) << text.out;
  EXPECT_NE(text.out.find("Savitzky-Golay derivative over 21 samples"), std::string::npos) << text.out;
  EXPECT_NE(text.out.find("noise floor"), std::string::npos) << text.out;
  EXPECT_NE(text.out.find("bias is zero by construction"), std::string::npos) << text.out;
}

TEST(EvaluateReal, ARulerOffsetIsRemovedAndReported) {
  TempDir dir;
  const fs::path sim = record(dir.path);
  const fs::path plain = rewrite(sim, dir.path / "plain.csv", kTruth);
  const fs::path shifted = rewrite(sim, dir.path / "shifted.csv", kTruth, [](std::size_t, std::string& cell) {
    cell = fixed9(std::strtod(cell.c_str(), nullptr) + 0.123);
  });
  const Result a = run_ve({"evaluate", "--log", plain.string(), "--json"}, dir.path);
  const Result b = run_ve({"evaluate", "--log", shifted.string(), "--json"}, dir.path);
  ASSERT_EQ(a.code, 0) << a.err;
  ASSERT_EQ(b.code, 0) << b.err;
  EXPECT_NEAR(json_number(b.out, {"ruler", "offset_m"}), 0.123, 1e-6) << b.out;
  EXPECT_NE(b.out.find("\"offset_mode\": \"auto\""), std::string::npos);
  EXPECT_NEAR(json_number(b.out, {"position_um", "bias"}), 0.0, 1e-6);
  EXPECT_NEAR(json_number(b.out, {"position_um", "rms"}), json_number(a.out, {"position_um", "rms"}), 1e-3);

  // Told there is none, the offset is the error; told its value, it is taken out.
  const Result none = run_ve({"evaluate", "--log", shifted.string(), "--json", "--ruler-offset", "none"}, dir.path);
  ASSERT_EQ(none.code, 0) << none.err;
  EXPECT_NEAR(json_number(none.out, {"position_um", "bias"}), -123000.0, 1.0) << none.out;
  const Result fixed = run_ve({"evaluate", "--log", shifted.string(), "--json", "--ruler-offset", "0.123"}, dir.path);
  ASSERT_EQ(fixed.code, 0) << fixed.err;
  EXPECT_NEAR(json_number(fixed.out, {"position_um", "bias"}), 0.0, 0.5) << fixed.out;
  EXPECT_NE(fixed.out.find("\"offset_mode\": \"fixed\""), std::string::npos);
}

TEST(EvaluateReal, AQuantisedRulerHasItsResolutionEstimated) {
  TempDir dir;
  const fs::path sim = record(dir.path);
  const Result truth = run_ve({"evaluate", "--log", sim.string(), "--json"}, dir.path);
  ASSERT_EQ(truth.code, 0) << truth.err;
  const fs::path coarse = rewrite(sim, dir.path / "coarse.csv", kTruth, [](std::size_t, std::string& cell) {
    cell = fixed9(std::round(std::strtod(cell.c_str(), nullptr) * 1e6) * 1e-6);
  });
  const Result r = run_ve({"evaluate", "--log", coarse.string(), "--json"}, dir.path);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NEAR(json_number(r.out, {"ruler", "resolution_um"}), 1.0, 1e-6) << r.out;
  EXPECT_NE(r.out.find("\"resolution_estimated\": true"), std::string::npos);
  EXPECT_NEAR(json_number(r.out, {"position_um", "rms"}), json_number(truth.out, {"position_um", "rms"}), 0.1 + 1.0);
  // A 1 um step over 21 samples at 4 kHz: about 0.04 mm/s of the ruler's own noise.
  const double floor = json_number(r.out, {"ruler", "velocity_resolution_floor_mmps"});
  EXPECT_GT(floor, 0.02);
  EXPECT_LT(floor, 0.08);
  EXPECT_NEAR(json_number(r.out, {"ruler", "noise_um"}), 1.0 / std::sqrt(12.0), 0.05);

  const Result text = run_ve({"evaluate", "--log", coarse.string()}, dir.path);
  ASSERT_EQ(text.code, 0) << text.err;
  EXPECT_NE(text.out.find("ruler resolution 1 um (estimated"), std::string::npos) << text.out;

  const Result given = run_ve({"evaluate", "--log", coarse.string(), "--json", "--ruler-resolution-um", "2"}, dir.path);
  ASSERT_EQ(given.code, 0) << given.err;
  EXPECT_NEAR(json_number(given.out, {"ruler", "resolution_um"}), 2.0, 1e-9);
  EXPECT_NE(given.out.find("\"resolution_estimated\": false"), std::string::npos);
}

TEST(EvaluateReal, RowsWithoutARulerReadingAreSkipped) {
  TempDir dir;
  const fs::path sim = record(dir.path);
  std::size_t blanked = 0;
  const fs::path gappy = rewrite(sim, dir.path / "gappy.csv", kTruth, [&](std::size_t row, std::string& cell) {
    if (row % 100 == 50) {
      cell.clear();
      ++blanked;
    }
  });
  const Result r = run_ve({"evaluate", "--log", gappy.string(), "--json"}, dir.path);
  ASSERT_EQ(r.code, 0) << r.err;
  ASSERT_GT(blanked, 0u);
  EXPECT_EQ(json_number(r.out, {"ruler", "rows_without_reference"}), static_cast<double>(blanked)) << r.out;
  EXPECT_EQ(json_number(r.out, {"evaluated"}), json_number(r.out, {"samples"}) - static_cast<double>(blanked));
  // Each gap restarts the derivative's window: fewer velocity samples than position ones.
  EXPECT_LT(json_number(r.out, {"ruler", "velocity_evaluated"}), json_number(r.out, {"evaluated"}));
  EXPECT_GT(json_number(r.out, {"ruler", "velocity_evaluated"}), 0.0);
}

TEST(EvaluateReal, WithoutTruthOrRulerOnlyConsistencyIsReported) {
  TempDir dir;
  const fs::path sim = record(dir.path);
  const fs::path bare = rewrite(sim, dir.path / "bare.csv", kTruthAndRuler);
  const Result r = run_ve({"evaluate", "--log", bare.string(), "--json"}, dir.path);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("\"basis\": \"none\""), std::string::npos) << r.out;
  EXPECT_EQ(r.out.find("\"position_um\""), std::string::npos);  // no accuracy without a reference
  const double nu_rms = json_number(r.out, {"innovation", "rms"});
  EXPECT_GT(nu_rms, 0.5) << r.out;
  EXPECT_LT(nu_rms, 2.0) << r.out;
  EXPECT_NEAR(json_number(r.out, {"innovation", "mean"}), 0.0, 0.2);
  EXPECT_LT(json_number(r.out, {"innovation", "beyond_6"}), 0.01);
  EXPECT_GT(json_number(r.out, {"valid_fraction"}), 0.99);
  EXPECT_EQ(json_number(r.out, {"status_fraction", "VALID"}), json_number(r.out, {"valid_fraction"}));
  EXPECT_EQ(json_number(r.out, {"status_fraction", "H3"}), 0.0);
  EXPECT_EQ(json_number(r.out, {"hall", "faulty"}), 0.0);
  const double p50 = json_number(r.out, {"position_std_um", "p50"});
  EXPECT_GT(p50, 0.0);
  EXPECT_LE(p50, json_number(r.out, {"position_std_um", "p95"}));
  EXPECT_GT(json_number(r.out, {"velocity_std_mmps", "p50"}), 0.0);
  EXPECT_FALSE(std::isnan(json_number(r.out, {"accel_bias_mps2", "end"})));

  const Result text = run_ve({"evaluate", "--log", bare.string()}, dir.path);
  ASSERT_EQ(text.code, 0) << text.err;
  EXPECT_NE(text.out.find("accuracy cannot be scored"), std::string::npos) << text.out;
  EXPECT_NE(text.out.find("normalised Hall innovation"), std::string::npos) << text.out;
}

TEST(EvaluateReal, AnUnknownRulerOffsetIsBadUsage) {
  TempDir dir;
  const fs::path sim = record(dir.path, 0.5);
  const fs::path ruler_log = rewrite(sim, dir.path / "ruler.csv", kTruth);
  const Result r = run_ve({"evaluate", "--log", ruler_log.string(), "--ruler-offset", "middle"}, dir.path);
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.err.find("--ruler-offset: 'middle'"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("auto, none"), std::string::npos) << r.err;
  EXPECT_TRUE(r.out.empty()) << r.out;
}

}  // namespace
