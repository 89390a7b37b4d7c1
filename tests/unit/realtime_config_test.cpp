// The machine file's `realtime:` section: defaults, both forms of cpu_affinity,
// and every problem reported at its file:line:column like the other fields.
#include <gtest/gtest.h>
#include <stdlib.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <string>
#include <utility>
#include <vector>

#include "config/loader.hpp"

namespace ve::config {
namespace {

namespace fs = std::filesystem;

class RtTempDir {
 public:
  RtTempDir() {
    std::string tmpl = (fs::temp_directory_path() / "ve-realtime-test-XXXXXX").string();
    if (!::mkdtemp(tmpl.data())) throw std::runtime_error("mkdtemp failed");
    path_ = tmpl;
    std::ofstream(path_ / "m.yaml") << "motor: test-motor\nmagnet_pitch_m: 0.012\ntravel_m: 1.0\n";
  }
  ~RtTempDir() {
    std::error_code ec;
    fs::remove_all(path_, ec);
  }
  /// A machine with axes x and y whose file starts with `realtime` (line 1 onwards).
  std::string machine(const std::string& realtime) const {
    const fs::path p = path_ / "machine.yaml";
    std::ofstream(p) << realtime << "axes:\n  - name: x\n    motor: m.yaml\n  - name: y\n    motor: m.yaml\n";
    return p.string();
  }

 private:
  fs::path path_;
};

const ConfigError* find_field(const LoadResult& r, const std::string& field) {
  for (const auto& e : r.errors)
    if (e.field == field) return &e;
  return nullptr;
}

void expect_error(const LoadResult& r, const std::string& file, int line, int column, const std::string& field,
                  const std::string& text) {
  const ConfigError* e = find_field(r, field);
  ASSERT_NE(e, nullptr) << "no error for field '" << field << "'; errors:\n" << to_string(r.errors);
  EXPECT_EQ(e->file, file);
  EXPECT_EQ(e->line, line) << e->to_string();
  EXPECT_EQ(e->column, column) << e->to_string();
  EXPECT_NE(e->message.find(text), std::string::npos) << e->to_string();
}

int configured_cpus() { return static_cast<int>(sysconf(_SC_NPROCESSORS_CONF)); }

TEST(RealtimeConfig, AbsentMeansEverythingOff) {
  RtTempDir dir;
  const auto r = load_machine_file(dir.machine(""));
  ASSERT_TRUE(r.ok()) << to_string(r.errors);
  const RealtimeConfig& c = r.config.realtime;
  EXPECT_EQ(c.sample_thread_priority, 0);
  EXPECT_TRUE(c.cpu_affinity.empty());
  EXPECT_TRUE(c.axis_cpu_affinity.empty());
  EXPECT_FALSE(c.lock_memory);
  EXPECT_FALSE(c.required);
  EXPECT_FALSE(c.any());
  EXPECT_TRUE(c.cpus_for("x").empty());
}

TEST(RealtimeConfig, EmbeddedDefaultHasNoRealtimeSettings) {
  const auto r = load_embedded_default();
  ASSERT_TRUE(r.ok()) << to_string(r.errors);
  EXPECT_FALSE(r.config.realtime.any());
}

TEST(RealtimeConfig, OneCpuListForEverySampleThread) {
  RtTempDir dir;
  const auto r = load_machine_file(dir.machine("realtime:\n"
                                               "  sample_thread_priority: 80\n"
                                               "  cpu_affinity: [0]\n"
                                               "  lock_memory: true\n"
                                               "  required: true\n"));
  ASSERT_TRUE(r.ok()) << to_string(r.errors);
  const RealtimeConfig& c = r.config.realtime;
  EXPECT_EQ(c.sample_thread_priority, 80);
  EXPECT_EQ(c.cpu_affinity, std::vector<int>{0});
  EXPECT_TRUE(c.lock_memory);
  EXPECT_TRUE(c.required);
  EXPECT_EQ(c.cpus_for("x"), std::vector<int>{0});
  EXPECT_EQ(c.cpus_for("y"), std::vector<int>{0});
}

TEST(RealtimeConfig, PerAxisCpuLists) {
  RtTempDir dir;
  const int last = configured_cpus() - 1;
  const auto r = load_machine_file(
      dir.machine("realtime:\n  cpu_affinity: {y: [" + std::to_string(last) + "]}\n"));
  ASSERT_TRUE(r.ok()) << to_string(r.errors);
  const RealtimeConfig& c = r.config.realtime;
  EXPECT_TRUE(c.cpu_affinity.empty());
  EXPECT_TRUE(c.cpus_for("x").empty()) << "an axis not named is not pinned";
  EXPECT_EQ(c.cpus_for("y"), std::vector<int>{last});
  EXPECT_TRUE(c.any());
}

TEST(RealtimeConfig, SampleLoopSharedByDefaultPerAxisOnRequest) {
  RtTempDir dir;
  const auto def = load_machine_file(dir.machine(""));
  ASSERT_TRUE(def.ok()) << to_string(def.errors);
  EXPECT_EQ(def.config.realtime.sample_loop, RealtimeConfig::SampleLoop::shared);
  EXPECT_FALSE(def.config.realtime.any()) << "the grouping of the sample threads is no privileged setting";
  const auto per_axis = load_machine_file(dir.machine("realtime:\n  sample_loop: per_axis\n"));
  ASSERT_TRUE(per_axis.ok()) << to_string(per_axis.errors);
  EXPECT_EQ(per_axis.config.realtime.sample_loop, RealtimeConfig::SampleLoop::per_axis);
  const auto path = dir.machine("realtime:\n  sample_loop: per_cpu\n");
  const auto bad = load_machine_file(path);
  ASSERT_EQ(bad.errors.size(), 1u) << to_string(bad.errors);
  expect_error(bad, path, 2, 16, "realtime.sample_loop", "is not one of");
}

TEST(RealtimeConfig, PriorityOutOfRange) {
  RtTempDir dir;
  const auto path = dir.machine("realtime:\n  sample_thread_priority: 100\n");
  const auto r = load_machine_file(path);
  ASSERT_EQ(r.errors.size(), 1u) << to_string(r.errors);
  expect_error(r, path, 2, 27, "realtime.sample_thread_priority", "must be in [0, 99]");
  const auto neg = load_machine_file(dir.machine("realtime:\n  sample_thread_priority: -1\n"));
  expect_error(neg, path, 2, 27, "realtime.sample_thread_priority", "got -1");
}

TEST(RealtimeConfig, DdsThreadsBelowTheSampleThreads) {
  RtTempDir dir;
  // Not given: normal scheduling, whatever the sample threads' priority.
  for (const int sample : {0, 1, 50}) {
    const auto r = load_machine_file(dir.machine("realtime:\n  sample_thread_priority: " + std::to_string(sample) + "\n"));
    ASSERT_TRUE(r.ok()) << to_string(r.errors);
    EXPECT_EQ(r.config.realtime.dds_thread_priority, 0) << "sample threads at " << sample;
  }
  const auto given = load_machine_file(dir.machine("realtime:\n  sample_thread_priority: 80\n  dds_thread_priority: 60\n"));
  ASSERT_TRUE(given.ok()) << to_string(given.errors);
  EXPECT_EQ(given.config.realtime.dds_thread_priority, 60);
  EXPECT_TRUE(given.config.realtime.any());

  const auto path = dir.machine("realtime:\n  sample_thread_priority: 50\n  dds_thread_priority: 50\n");
  const auto same = load_machine_file(path);
  ASSERT_EQ(same.errors.size(), 1u) << to_string(same.errors);
  expect_error(same, path, 3, 24, "realtime.dds_thread_priority", "must be below realtime.sample_thread_priority (50");
  const auto alone = load_machine_file(dir.machine("realtime:\n  dds_thread_priority: 10\n"));
  expect_error(alone, path, 2, 24, "realtime.dds_thread_priority", "normal scheduling, got 10");
  const auto range = load_machine_file(dir.machine("realtime:\n  sample_thread_priority: 50\n  dds_thread_priority: -2\n"));
  expect_error(range, path, 3, 24, "realtime.dds_thread_priority", "must be in [0, 99]");
}

TEST(RealtimeConfig, WrongTypes) {
  RtTempDir dir;
  const auto path = dir.machine("realtime:\n"
                                "  sample_thread_priority: high\n"
                                "  lock_memory: yes\n"
                                "  cpu_affinity: 2\n");
  const auto r = load_machine_file(path);
  EXPECT_EQ(r.errors.size(), 3u) << to_string(r.errors);
  expect_error(r, path, 2, 27, "realtime.sample_thread_priority", "expected an integer, got 'high'");
  expect_error(r, path, 3, 16, "realtime.lock_memory", "expected true or false");
  expect_error(r, path, 4, 17, "realtime.cpu_affinity", "expected a list of CPU indices");
}

TEST(RealtimeConfig, CpuBeyondThisMachineIsAnError) {
  RtTempDir dir;
  const int n = configured_cpus();
  const auto path = dir.machine("realtime:\n  cpu_affinity: [0, " + std::to_string(n) + "]\n");
  const auto r = load_machine_file(path);
  ASSERT_EQ(r.errors.size(), 1u) << to_string(r.errors);
  expect_error(r, path, 2, 21, "realtime.cpu_affinity[1]",
               "CPU " + std::to_string(n) + " does not exist on this machine (it has CPUs 0-" + std::to_string(n - 1) + ")");
  EXPECT_TRUE(r.config.realtime.cpu_affinity.empty());
}

TEST(RealtimeConfig, BadCpuListsAreReportedElementByElement) {
  RtTempDir dir;
  const auto path = dir.machine("realtime:\n"
                                "  cpu_affinity: {x: [0, 0], y: [-1], z: [0], w: 3}\n"
                                "  requird: true\n");
  const auto r = load_machine_file(path);
  EXPECT_EQ(r.errors.size(), 5u) << to_string(r.errors);
  expect_error(r, path, 2, 25, "realtime.cpu_affinity.x[1]", "CPU 0 is listed twice");
  expect_error(r, path, 2, 33, "realtime.cpu_affinity.y[0]", "must be in [0, 1023], got -1");
  expect_error(r, path, 2, 38, "realtime.cpu_affinity.z", "unknown key 'z'");
  expect_error(r, path, 2, 46, "realtime.cpu_affinity.w", "unknown key 'w'");
  expect_error(r, path, 3, 3, "realtime.requird", "did you mean 'required'?");
}

TEST(RealtimeConfig, EmptyCpuListIsAnError) {
  RtTempDir dir;
  const auto path = dir.machine("realtime:\n  cpu_affinity: []\n");
  const auto r = load_machine_file(path);
  ASSERT_EQ(r.errors.size(), 1u) << to_string(r.errors);
  expect_error(r, path, 2, 17, "realtime.cpu_affinity", "must list at least one CPU");
}

TEST(RealtimeConfig, ShippedSoakMachineLoads) {
  const auto r = load_machine_file(std::string(VE_SOURCE_DIR) + "/config/machines/sim-3axis.yaml");
  ASSERT_TRUE(r.ok()) << to_string(r.errors);
  ASSERT_EQ(r.config.axes.size(), 3u);
  for (const auto& a : r.config.axes) EXPECT_DOUBLE_EQ(a.motor.sample_rate_hz, 4000.0) << a.name;
}

}  // namespace
}  // namespace ve::config
