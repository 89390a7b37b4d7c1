// docs/configuration.md documents every key of every file kind. This test keeps the
// reference and the loaders in step: it fails, naming the key, when a loader accepts a
// key the reference does not document, or the reference documents one no loader accepts.
//
// The accepted keys are what the loaders themselves declare valid (the list their
// unknown-key check uses), recorded by schema::KeyRecorder while they read probe files
// that take every variant: each driver type (sim, replay, socketcan), a fault, both
// forms of realtime.cpu_affinity, every CAN signal. Keys are declared whether or not
// the file holds them, so the probes stay short; the errors they cause do not matter.
// A key the loaders refuse as valid only in another variant must be read by a probe
// of that variant, so a new variant without a probe fails here too.
#include <gtest/gtest.h>
#include <stdlib.h>

#include <filesystem>
#include <fstream>
#include <map>
#include <regex>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "config/calibration_file.hpp"
#include "config/loader.hpp"
#include "../integration/temp_dir.hpp"
#include "core/motor.hpp"
#include "config/can_layout_file.hpp"

namespace ve::config {
namespace {

namespace fs = std::filesystem;

using KeySets = std::map<std::string, std::set<std::string>>;  // file kind -> key paths

const char* const kKinds[] = {"machine", "motor", "calibration", "can_layout"};
constexpr const char* kReference = VE_SOURCE_DIR "/docs/configuration.md";
constexpr const char* kProbeAxis = "probe";

/// A scratch folder, removed with the test (tests/integration/temp_dir.hpp).
struct TempDir : ve::test::TempDir {
  TempDir() : ve::test::TempDir("ve_reference_test") {}
};

std::string machine_probe(const std::string& driver, const std::string& realtime) {
  return "machine: probe\n"
         "dds: {}\n"
         "axes:\n"
         "  - name: " + std::string(kProbeAxis) + "\n"
         "    motor: motor.yaml\n"
         "    calibration: cal.yaml\n"
         "    driver: " + driver + "\n"
         "    homing: {mode: signature}\n"
         "realtime: " + realtime + "\n";
}

/// The file kind of a probe file, by its name.
std::string kind_of(const std::string& file) {
  const std::string name = fs::path(file).filename().string();
  if (name.rfind("machine", 0) == 0) return "machine";
  if (name == "motor.yaml") return "motor";
  if (name == "cal.yaml") return "calibration";
  if (name == "layout.yaml") return "can_layout";
  return "";
}

/// Key paths as the reference writes them: the probe axis' name under
/// realtime.cpu_affinity is any axis name, signals.hall_0 .. hall_7 are signals.hall_<i>.
std::string reference_form(const std::string& kind, const std::string& path) {
  static const std::regex hall_signal(R"(^signals\.hall_[0-9]+)");
  if (kind == "machine" && path == std::string("realtime.cpu_affinity.") + kProbeAxis)
    return "realtime.cpu_affinity.<axis name>";
  if (kind == "can_layout") return std::regex_replace(path, hall_signal, "signals.hall_<i>");
  return path;
}

/// The last name of a key path: "signals.hall_0.in_can_id" -> "in_can_id".
std::string leaf(const std::string& path) {
  const auto dot = path.rfind('.');
  return dot == std::string::npos ? path : path.substr(dot + 1);
}

KeySets accepted_keys() {
  TempDir dir;
  dir.write("motor.yaml", "motor: probe\n");
  std::string signals;
  for (int i = 0; i < core::kMaxHalls; ++i) signals += "hall_" + std::to_string(i) + ": {}, ";
  dir.write("layout.yaml", "signals: {" + signals + "accel: {}, accel_base: {}, sequence: {}, node_timestamp: {}, temperature: {}}\n");
  const std::string cal = dir.write("cal.yaml", std::string("format: ") + kCalibrationFormat +
                                                    "\nversion: " + std::to_string(kCalibrationVersion) + "\ntable: {}\n");
  const std::vector<std::string> machines = {
      dir.write("machine-sim.yaml", machine_probe("{type: sim, faults: [{kind: hall_noisy}]}",
                                                  std::string("{cpu_affinity: {") + kProbeAxis + ": [0]}}")),
      dir.write("machine-replay.yaml", machine_probe("{type: replay, log: probe.log}", "{cpu_affinity: [0]}")),
      dir.write("machine-can.yaml", machine_probe("{type: socketcan, interface: can0, layout: layout.yaml}", "{}")),
  };

  schema::KeyRecorder recorder;
  for (const auto& m : machines) load_machine_file(m, LoadOptions{});
  core::MotorConfig motor;
  motor.name = "probe";
  load_calibration_file(cal, motor);

  KeySets keys;
  for (const auto& k : recorder.keys()) {
    const std::string kind = kind_of(k.file);
    EXPECT_FALSE(kind.empty()) << "key " << k.path << " recorded for an unexpected file " << k.file;
    if (!kind.empty()) keys[kind].insert(reference_form(kind, k.path));
  }
  // A key refused as "only used with" another variant must have been read in that
  // variant by some probe, else the probes miss a branch of the loader (a key only
  // the sequence signal takes is refused for the other signals, so compare names).
  KeySets rejected;
  for (const auto& k : recorder.rejected()) rejected[kind_of(k.file)].insert(reference_form(kind_of(k.file), k.path));
  for (const auto& [kind, paths] : rejected)
    for (const auto& path : paths) {
      bool reached = false;
      for (const auto& a : keys[kind]) reached = reached || leaf(a) == leaf(path);
      EXPECT_TRUE(reached) << kind << " key " << path
                           << " is refused as valid only in another variant, which no probe file reads";
    }
  return keys;
}

/// The reference's key rows: in a section headed "## Machine file", "## Motor file",
/// "## Calibration file" or "## CAN layout file", a table row whose first cell is a key
/// path in backticks.
KeySets documented_keys(std::vector<std::string>& duplicates) {
  static const std::map<std::string, std::string> sections = {{"## Machine file", "machine"},
                                                              {"## Motor file", "motor"},
                                                              {"## Calibration file", "calibration"},
                                                              {"## CAN layout file", "can_layout"}};
  static const std::regex row(R"(^\|\s*`([^`]+)`\s*\|)");
  std::ifstream in(kReference);
  EXPECT_TRUE(in.good()) << "cannot read " << kReference;
  KeySets keys;
  std::string kind, line;
  while (std::getline(in, line)) {
    if (line.rfind("## ", 0) == 0) {
      const auto it = sections.find(line);
      kind = it == sections.end() ? "" : it->second;
      continue;
    }
    std::smatch m;
    if (kind.empty() || !std::regex_search(line, m, row)) continue;
    if (!keys[kind].insert(m[1].str()).second) duplicates.push_back(kind + ": " + m[1].str());
  }
  return keys;
}

TEST(ConfigurationReference, DocumentsExactlyTheKeysTheLoadersAccept) {
  const KeySets accepted = accepted_keys();
  std::vector<std::string> duplicates;
  const KeySets documented = documented_keys(duplicates);
  for (const auto& d : duplicates) ADD_FAILURE() << kReference << ": key documented twice: " << d;

  // The probes themselves: each kind was read, through the branches that matter.
  const std::map<std::string, std::string> samples = {
      {"machine", "axes[].driver.imperfections.frame_vibration_hz"},
      {"machine", "axes[].driver.log"},
      {"machine", "axes[].driver.layout"},
      {"motor", "filter.hall_gain_tc_per_k"},
      {"calibration", "table.step_m"},
      {"can_layout", "signals.sequence.in_can_id"}};
  for (const auto& [kind, key] : samples) {
    const auto it = accepted.find(kind);
    EXPECT_TRUE(it != accepted.end() && it->second.count(key)) << "the probe did not reach " << kind << " key " << key;
  }

  for (const char* kind : kKinds) {
    const auto a = accepted.find(kind);
    const auto d = documented.find(kind);
    const std::set<std::string> none;
    const std::set<std::string>& acc = a == accepted.end() ? none : a->second;
    const std::set<std::string>& doc = d == documented.end() ? none : d->second;
    for (const auto& k : acc)
      if (!doc.count(k))
        ADD_FAILURE() << kind << " file: key `" << k << "` is accepted by the loader but not documented in "
                      << kReference;
    for (const auto& k : doc)
      if (!acc.count(k))
        ADD_FAILURE() << kind << " file: key `" << k << "` is documented in " << kReference
                      << " but the loader does not accept it";
    RecordProperty(std::string("keys_") + kind, static_cast<int>(acc.size()));
  }
}

}  // namespace
}  // namespace ve::config
