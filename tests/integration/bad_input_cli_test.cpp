// Bad input on the command line, signals and disk errors, as a user or an operator
// meets them, table-driven: every case runs the real binary and asserts
//  - the exit-code class (2 bad command line or input, 1 the job failed, 0 done,
//    128 + signal interrupted before the job was done),
//  - that the process exited (no death by a signal, no hang: a 20 s watchdog),
//  - that stderr names the option, file or path at fault (and the system's reason for
//    file-system errors), and that nothing half-written or `.partial` is left behind.
// The command-line cases also check the form of a parse error: one line saying what
// is wrong, then one usage line.
#include <gtest/gtest.h>

#include <fcntl.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "replay/raw_log.hpp"
#include "temp_dir.hpp"
#include "test_domain.hpp"

namespace {

using namespace std::chrono_literals;
namespace fs = std::filesystem;

extern "C" char** environ;

std::string slurp(const fs::path& p) {
  std::ifstream in(p);
  std::string s((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  return s;
}

void write_text(const fs::path& p, const std::string& text) {
  std::ofstream out(p);
  out << text;
}

/// How a child ended.
struct Outcome {
  bool exited = false;    ///< normal exit (not killed by a signal, not the watchdog)
  int code = -1;          ///< exit code when exited
  int signal = 0;         ///< signal that killed it, if any
  bool hung = false;      ///< the watchdog killed it
  double seconds = 0.0;   ///< from start (or from the signal sent) to the end
  std::string out, err;
};

std::string describe(const Outcome& o) {
  std::string s = o.hung ? "HUNG (killed by the watchdog)"
                  : o.exited ? "exit " + std::to_string(o.code)
                             : "killed by signal " + std::to_string(o.signal);
  return s + "\n--- stdout:\n" + o.out.substr(0, 4000) + "\n--- stderr:\n" + o.err.substr(0, 4000);
}

/// The binary in a process group of its own, stdout and stderr read through pipes
/// (not files: RLIMIT_FSIZE, when given, must limit only what the program writes
/// itself), stdin /dev/null; the whole group is killed with the object.
class Child {
 public:
  Child(const std::vector<std::string>& args, long fsize_limit = -1) {
    std::vector<std::string> full{VE_BINARY};
    full.insert(full.end(), args.begin(), args.end());
    std::vector<char*> argv;
    for (auto& a : full) argv.push_back(const_cast<char*>(a.c_str()));
    argv.push_back(nullptr);
    int out[2], err[2];
    if (pipe2(out, O_CLOEXEC) != 0) return;
    if (pipe2(err, O_CLOEXEC) != 0) {
      close(out[0]);
      close(out[1]);
      return;
    }
    const pid_t parent = getpid();
    start_ = std::chrono::steady_clock::now();
    pid_ = fork();
    if (pid_ == 0) {
      setpgid(0, 0);
      if (prctl(PR_SET_PDEATHSIG, SIGKILL) != 0 || getppid() != parent) _exit(127);
      const int in = open("/dev/null", O_RDONLY);
      if (in < 0 || dup2(in, 0) < 0 || dup2(out[1], 1) < 0 || dup2(err[1], 2) < 0) _exit(127);
      if (fsize_limit >= 0) {
        const rlimit r{static_cast<rlim_t>(fsize_limit), static_cast<rlim_t>(fsize_limit)};
        if (setrlimit(RLIMIT_FSIZE, &r) != 0) _exit(127);
      }
      execve(argv[0], argv.data(), environ);
      _exit(127);
    }
    close(out[1]);
    close(err[1]);
    out_fd_ = out[0];
    err_fd_ = err[0];
    fcntl(out_fd_, F_SETFL, O_NONBLOCK);
    fcntl(err_fd_, F_SETFL, O_NONBLOCK);
    if (pid_ > 0) setpgid(pid_, pid_);  // also from here: the group exists before any kill below
  }
  ~Child() {
    if (pid_ > 0 && !reaped_) {
      kill(-pid_, SIGKILL);
      int st;
      waitpid(pid_, &st, 0);
    }
    if (out_fd_ >= 0) close(out_fd_);
    if (err_fd_ >= 0) close(err_fd_);
  }
  Child(const Child&) = delete;
  Child& operator=(const Child&) = delete;

  bool started() const { return pid_ > 0; }
  /// Sends `sig` to the child unless it has already been reaped (its pid may be another's by then).
  void signal(int sig) {
    if (pid_ <= 0 || reaped_) return;
    signalled_ = std::chrono::steady_clock::now();
    kill(pid_, sig);
  }
  bool running() {
    drain();
    if (reaped_ || pid_ <= 0) return false;
    int st = 0;
    if (waitpid(pid_, &st, WNOHANG) != pid_) return true;
    finish(st);
    return false;
  }
  /// Waits for the end, at most `watchdog`; the time counts from the signal if one was sent.
  Outcome wait(std::chrono::milliseconds watchdog = 20s) {
    const auto until = std::chrono::steady_clock::now() + watchdog;
    while (running() && std::chrono::steady_clock::now() < until) std::this_thread::sleep_for(5ms);
    if (!reaped_ && pid_ > 0) {
      kill(-pid_, SIGKILL);
      int st = 0;
      waitpid(pid_, &st, 0);
      finish(st);
      outcome_.hung = true;
      outcome_.exited = false;
    }
    // What is left in the pipes (a grandchild could hold them open: do not wait for EOF).
    for (int i = 0; i < 50 && drain(); ++i) {
    }
    return outcome_;
  }

 private:
  /// Reads what is in the pipes; true when anything was read.
  bool drain() {
    bool any = false;
    char buf[65536];
    for (auto [fd, text] : {std::pair{out_fd_, &outcome_.out}, std::pair{err_fd_, &outcome_.err}}) {
      if (fd < 0) continue;
      for (ssize_t n; (n = read(fd, buf, sizeof buf)) > 0;) {
        text->append(buf, static_cast<std::size_t>(n));
        any = true;
      }
    }
    return any;
  }
  void finish(int st) {
    reaped_ = true;
    const auto end = std::chrono::steady_clock::now();
    const auto from = signalled_ ? *signalled_ : start_;
    outcome_.seconds = std::chrono::duration<double>(end - from).count();
    outcome_.exited = WIFEXITED(st);
    outcome_.code = WIFEXITED(st) ? WEXITSTATUS(st) : -1;
    outcome_.signal = WIFSIGNALED(st) ? WTERMSIG(st) : 0;
  }

  pid_t pid_ = -1;
  int out_fd_ = -1, err_fd_ = -1;
  bool reaped_ = false;
  std::chrono::steady_clock::time_point start_;
  std::optional<std::chrono::steady_clock::time_point> signalled_;
  Outcome outcome_;
};

Outcome run_to_end(const std::vector<std::string>& args, const fs::path& /*dir*/, long fsize_limit = -1) {
  Child c(args, fsize_limit);
  EXPECT_TRUE(c.started());
  return c.wait(60s);  // a calibration of the simulator takes a few seconds, more under a sanitizer
}

std::size_t lines(const std::string& s) { return static_cast<std::size_t>(std::count(s.begin(), s.end(), '\n')); }

/// Files in `dir` whose names contain `part` (".partial", ".tmp.").
std::vector<std::string> leftovers(const fs::path& dir, const std::string& part) {
  std::vector<std::string> found;
  std::error_code ec;
  for (const auto& e : fs::recursive_directory_iterator(dir, ec))
    if (e.path().filename().string().find(part) != std::string::npos) found.push_back(e.path().string());
  return found;
}

/// Shared inputs, each made on first use (ctest runs every case in a process of its
/// own): a short raw log of the built-in simulator and a longer one.
struct Inputs {
  ve::test::TempDir dir{"ve_bad_cli"};
  const fs::path& short_log() { return made(short_log_, "short.csv", "0.25"); }
  const fs::path& long_log() { return made(long_log_, "long.csv", "60"); }

 private:
  const fs::path& made(fs::path& path, const char* name, const char* seconds) {
    if (path.empty()) {
      path = dir.path / name;
      const Outcome o = run_to_end({"record", "--out", path.string(), "--duration", seconds, "--fast"}, dir.path);
      if (o.code != 0) ADD_FAILURE() << describe(o);
    }
    return path;
  }
  fs::path short_log_, long_log_;
};
Inputs& inputs() {
  static Inputs in;  // removed at the end of the process
  return in;
}

/// Replaces {dir}, {log}, {long} and {file} in the arguments; {file} is a regular file
/// made in the case's directory, for paths "under a regular file".
std::vector<std::string> expand(std::vector<std::string> args, const fs::path& dir) {
  for (auto& a : args) {
    auto put = [&a](const std::string& key, const std::string& value) {
      for (std::size_t at; (at = a.find(key)) != std::string::npos;) a.replace(at, key.size(), value);
    };
    put("{dir}", dir.string());
    put("{file}", (dir / "a_file").string());
    if (a.find("{log}") != std::string::npos) put("{log}", inputs().short_log().string());
    if (a.find("{long}") != std::string::npos) put("{long}", inputs().long_log().string());
    put("{src}", VE_SOURCE_DIR);
  }
  return args;
}

// =========================================================== the command line

struct UsageCase {
  const char* name;
  std::vector<std::string> args;
  const char* names;  ///< what stderr must name (the option or the word at fault)
};

std::ostream& operator<<(std::ostream& os, const UsageCase& c) { return os << c.name; }

class CommandLine : public ::testing::TestWithParam<UsageCase> {};

// Exit 2, one line naming what is wrong then one usage line, nothing on stdout.
TEST_P(CommandLine, RefusedWithExit2AndAUsageHint) {
  const UsageCase& c = GetParam();
  ve::test::TempDir dir;
  write_text(dir.path / "a_file", "x\n");
  const Outcome o = run_to_end(expand(c.args, dir.path), dir.path);
  ASSERT_TRUE(o.exited) << describe(o);
  EXPECT_EQ(o.code, 2) << describe(o);
  EXPECT_NE(o.err.find(c.names), std::string::npos) << "stderr should name '" << c.names << "'\n" << describe(o);
  EXPECT_NE(o.err.find("usage: virtual-encoder"), std::string::npos) << describe(o);
  EXPECT_EQ(lines(o.err), 2u) << "one line for the error, one for the usage\n" << describe(o);
  EXPECT_TRUE(o.out.empty()) << describe(o);
}

// clang-format off
const UsageCase kUsageCases[] = {
  {"NoArguments", {}, "subcommand"},
  {"UnknownSubcommand", {"bogus"}, "'bogus'"},
  {"UnknownSubcommandAfterLogLevel", {"--log-level", "info", "frobnicate"}, "'frobnicate'"},
  {"UnknownGlobalOption", {"--bogus", "check"}, "--bogus"},
  {"LogLevelBogusGlobal", {"--log-level", "bogus", "check"}, "--log-level"},
  {"LogLevelBogusAfterSubcommand", {"check", "--log-level", "bogus"}, "--log-level"},
  {"LogLevelEmpty", {"check", "--log-level", ""}, "--log-level"},
  {"LogLevelMissingValue", {"check", "--log-level"}, "--log-level"},
  {"LogLevelUppercase", {"check", "--log-level", "INFO"}, "--log-level"},
  {"CheckUnknownOption", {"check", "--frobnicate"}, "--frobnicate"},
  {"CheckExtraArgument", {"check", "extra"}, "extra"},
  {"CheckConfigMissingValue", {"check", "--config"}, "--config"},
  {"RunDurationNaN", {"run", "--duration", "nan"}, "--duration"},
  {"RunDurationInf", {"run", "--duration", "inf"}, "--duration"},
  {"RunDurationMinusInf", {"run", "--duration", "-inf"}, "--duration"},
  {"RunDurationNegative", {"run", "--duration", "-1"}, "--duration"},
  {"RunDurationText", {"run", "--duration", "ten"}, "--duration"},
  {"RunDurationOverflow", {"run", "--duration", "1e400"}, "--duration"},
  {"RunDurationTooLong", {"run", "--duration", "1e12"}, "--duration"},
  {"RunDurationTrailingJunk", {"run", "--duration", "5s"}, "--duration"},
  {"RunDurationMissingValue", {"run", "--duration"}, "--duration"},
  {"RunWaitForSubscriberNaN", {"run", "--wait-for-subscriber", "nan"}, "--wait-for-subscriber"},
  {"RunWaitForSubscriberNegative", {"run", "--wait-for-subscriber", "-3"}, "--wait-for-subscriber"},
  {"RunStatusPeriodZero", {"run", "--status-period", "0"}, "--status-period"},
  {"RunStatusPeriodNegative", {"run", "--status-period", "-1"}, "--status-period"},
  {"RunStatusPeriodNaN", {"run", "--status-period", "nan"}, "--status-period"},
  {"RunStatusPeriodInf", {"run", "--status-period", "inf"}, "--status-period"},
  {"RunDomainNegative", {"run", "--domain", "-1"}, "--domain"},
  {"RunDomainTooLarge", {"run", "--domain", "233"}, "--domain"},
  {"RunDomainNotInteger", {"run", "--domain", "1.5"}, "--domain"},
  {"RunDomainText", {"run", "--domain", "seven"}, "--domain"},
  {"RunHasNoStallOption", {"run", "--stall-axis", "x"}, "--stall-axis"},
  {"RunUnknownOption", {"run", "--durations", "1"}, "--durations"},
  {"MonitorDurationNaN", {"monitor", "--duration", "nan"}, "--duration"},
  {"MonitorDurationNegative", {"monitor", "--duration", "-5"}, "--duration"},
  {"MonitorDeadlineNaN", {"monitor", "--deadline-ms", "nan"}, "--deadline-ms"},
  {"MonitorDeadlineNegative", {"monitor", "--deadline-ms", "-1"}, "--deadline-ms"},
  {"MonitorDeadlineInf", {"monitor", "--deadline-ms", "inf"}, "--deadline-ms"},
  {"MonitorDomainTooLarge", {"monitor", "--domain", "999"}, "--domain"},
  {"MonitorCsvWithAWrongValue", {"monitor", "--csv=maybe"}, "--csv"},
  {"RecordOutMissing", {"record", "--duration", "1"}, "--out"},
  {"RecordOutMissingValue", {"record", "--out"}, "--out"},
  {"RecordDurationNaN", {"record", "--out", "{dir}/r.csv", "--duration", "nan"}, "--duration"},
  {"RecordDurationInf", {"record", "--out", "{dir}/r.csv", "--duration", "inf"}, "--duration"},
  {"RecordDurationNegative", {"record", "--out", "{dir}/r.csv", "--duration", "-1"}, "--duration"},
  {"RecordDurationHuge", {"record", "--out", "{dir}/r.csv", "--duration", "1e300"}, "--duration"},
  {"RecordDurationHex", {"record", "--out", "{dir}/r.csv", "--duration", "0x1p2000"}, "--duration"},
  {"RecordFirstSampleTimeoutZero", {"record", "--out", "{dir}/r.csv", "--first-sample-timeout", "0"}, "--first-sample-timeout"},
  {"RecordFirstSampleTimeoutNaN", {"record", "--out", "{dir}/r.csv", "--first-sample-timeout", "nan"}, "--first-sample-timeout"},
  {"RecordFastWithValue", {"record", "--out", "{dir}/r.csv", "--fast=maybe"}, "--fast"},
  {"EvaluateLogMissing", {"evaluate"}, "--log"},
  {"EvaluateHomeNaN", {"evaluate", "--log", "{log}", "--home", "nan"}, "--home"},
  {"EvaluateHomeInf", {"evaluate", "--log", "{log}", "--home", "inf"}, "--home"},
  {"EvaluateHomeText", {"evaluate", "--log", "{log}", "--home", "middle"}, "--home"},
  {"EvaluateHomeHuge", {"evaluate", "--log", "{log}", "--home", "1e300"}, "--home"},
  {"EvaluateRulerOffsetWord", {"evaluate", "--log", "{log}", "--ruler-offset", "automatic"}, "--ruler-offset"},
  {"EvaluateRulerOffsetNaN", {"evaluate", "--log", "{log}", "--ruler-offset", "nan"}, "--ruler-offset"},
  {"EvaluateRulerOffsetInf", {"evaluate", "--log", "{log}", "--ruler-offset", "-inf"}, "--ruler-offset"},
  {"EvaluateRulerOffsetHuge", {"evaluate", "--log", "{log}", "--ruler-offset", "1e9"}, "--ruler-offset"},
  {"EvaluateRulerResolutionNegative", {"evaluate", "--log", "{log}", "--ruler-resolution-um", "-1"}, "--ruler-resolution-um"},
  {"EvaluateRulerResolutionNaN", {"evaluate", "--log", "{log}", "--ruler-resolution-um", "nan"}, "--ruler-resolution-um"},
  {"EvaluateHalfWindowZero", {"evaluate", "--log", "{log}", "--ruler-half-window", "0"}, "--ruler-half-window"},
  {"EvaluateHalfWindowTooLarge", {"evaluate", "--log", "{log}", "--ruler-half-window", "10001"}, "--ruler-half-window"},
  {"EvaluateHalfWindowFraction", {"evaluate", "--log", "{log}", "--ruler-half-window", "2.5"}, "--ruler-half-window"},
  {"EvaluateJsonWithAWrongValue", {"evaluate", "--log", "{log}", "--json=perhaps"}, "--json"},
  {"CalibrateSpeedZero", {"calibrate", "--speed", "0"}, "--speed"},
  {"CalibrateSpeedTooFast", {"calibrate", "--speed", "1"}, "--speed"},
  {"CalibrateSpeedNaN", {"calibrate", "--speed", "nan"}, "--speed"},
  {"CalibrateSpeedNegative", {"calibrate", "--speed", "-0.01"}, "--speed"},
  {"CalibrateHallDelayNaN", {"calibrate", "--no-reference", "--hall-delay-us", "nan"}, "--hall-delay-us"},
  {"CalibrateHallDelayNegative", {"calibrate", "--no-reference", "--hall-delay-us", "-1"}, "--hall-delay-us"},
  {"CalibrateAccelDelayInf", {"calibrate", "--no-reference", "--accel-delay-us", "inf"}, "--accel-delay-us"},
  {"CalibrateAccelDelayHuge", {"calibrate", "--no-reference", "--accel-delay-us", "1e9"}, "--accel-delay-us"},
  {"CalibrateBothDelays", {"calibrate", "--no-reference", "--hall-delay-us", "20", "--accel-delay-us", "250"}, "--accel-delay-us"},
  {"CalibrateUnknownOption", {"calibrate", "--sped", "0.02"}, "--sped"},
  {"SensorNodeLayoutMissing", {"sensor-node"}, "--layout"},
  {"SensorNodeDurationNaN", {"sensor-node", "--layout", "{file}", "--duration", "nan"}, "--duration"},
  {"SensorNodeDurationNegative", {"sensor-node", "--layout", "{file}", "--duration", "-2"}, "--duration"},
  {"SensorNodeDropAtNegative", {"sensor-node", "--layout", "{file}", "--drop-at", "-1"}, "--drop-at"},
  {"SensorNodeDropAtNaN", {"sensor-node", "--layout", "{file}", "--drop-at", "nan"}, "--drop-at"},
  {"SensorNodeDropCountHuge", {"sensor-node", "--layout", "{file}", "--drop-count", "1e20"}, "--drop-count"},
  {"SensorNodeDropCountFraction", {"sensor-node", "--layout", "{file}", "--drop-count", "1.5"}, "--drop-count"},
};
// clang-format on

INSTANTIATE_TEST_SUITE_P(BadInput, CommandLine, ::testing::ValuesIn(kUsageCases),
                         [](const auto& info) { return std::string(info.param.name); });

// ======================= values the command line can only check against the machine file

struct ValueCase {
  const char* name;
  std::vector<std::string> args;
  int code;
  std::vector<std::string> names;  ///< what stderr must name
};

std::ostream& operator<<(std::ostream& os, const ValueCase& c) { return os << c.name; }

class CommandLineValue : public ::testing::TestWithParam<ValueCase> {};

TEST_P(CommandLineValue, RefusedNamingTheValue) {
  const ValueCase& c = GetParam();
  ve::test::TempDir dir;
  write_text(dir.path / "a_file", "x\n");
  const Outcome o = run_to_end(expand(c.args, dir.path), dir.path);
  ASSERT_TRUE(o.exited) << describe(o);
  EXPECT_EQ(o.code, c.code) << describe(o);
  for (const auto& n : expand(c.names, dir.path))
    EXPECT_NE(o.err.find(n), std::string::npos) << "stderr should name '" << n << "'\n" << describe(o);
  EXPECT_TRUE(leftovers(dir.path, ".partial").empty()) << describe(o);
  EXPECT_TRUE(leftovers(dir.path, ".tmp.").empty()) << describe(o);
}

// clang-format off
const ValueCase kValueCases[] = {
  {"EvaluateHomeBeyondTravel", {"evaluate", "--log", "{log}", "--home", "5"}, 2, {"--home", "5 m", "travel"}},
  {"EvaluateHomeFarBeyondTravel", {"evaluate", "--log", "{log}", "--home", "1e5"}, 2, {"--home", "travel"}},
  {"EvaluateHomeNegative", {"evaluate", "--log", "{log}", "--home", "-0.1"}, 2, {"--home", "travel"}},
  {"EvaluateUnknownAxis", {"evaluate", "--log", "{log}", "--axis", "nosuch"}, 2, {"nosuch"}},
  {"RecordUnknownAxis", {"record", "--out", "{dir}/r.csv", "--axis", "nosuch"}, 2, {"nosuch"}},
  {"CalibrateUnknownAxis", {"calibrate", "--axis", "nosuch", "--out", "{dir}/c.cal.yaml"}, 2, {"nosuch"}},
  {"EvaluateEstimatesOverTheLog", {"evaluate", "--log", "{log}", "--estimates", "{log}"}, 2, {"--estimates", "{log}"}},
  {"CalibrateOutOverTheLog", {"calibrate", "--log", "{log}", "--out", "{log}"}, 2, {"--out", "{log}"}},
  {"EvaluateMissingLog", {"evaluate", "--log", "{dir}/nosuch.csv"}, 2, {"{dir}/nosuch.csv", "No such file"}},
  {"EvaluateLogIsDevZero", {"evaluate", "--log", "/dev/zero"}, 2, {"/dev/zero", "device"}},
  {"EvaluateLogIsADirectory", {"evaluate", "--log", "{dir}"}, 2, {"{dir}", "directory"}},
  {"EvaluateLogUnderAFile", {"evaluate", "--log", "{file}/x.csv"}, 2, {"{file}/x.csv", "Not a directory"}},
  {"EvaluateConfigIsDevZero", {"evaluate", "--config", "/dev/zero", "--log", "{log}"}, 2, {"/dev/zero"}},
  {"RecordConfigUnderAFile", {"record", "--config", "{file}/m.yaml", "--out", "{dir}/r.csv"}, 2, {"{file}/m.yaml", "Not a directory"}},
  {"EvaluateCalibrationIsDevZero", {"evaluate", "--log", "{log}", "--calibration", "/dev/zero"}, 2, {"/dev/zero"}},
  {"EvaluateCalibrationUnderAFile", {"evaluate", "--log", "{log}", "--calibration", "{file}/x.cal.yaml"}, 2, {"{file}/x.cal.yaml", "Not a directory"}},
  {"CalibrateLogIsDevZero", {"calibrate", "--log", "/dev/zero", "--out", "{dir}/c.cal.yaml"}, 2, {"/dev/zero", "device"}},
  {"CalibrateLogIsADirectory", {"calibrate", "--log", "{dir}", "--out", "{dir}/c.cal.yaml"}, 2, {"{dir}", "directory"}},
  // Readable but without the motion a calibration needs: the job fails (1), naming the log.
  {"CalibrateLogWithoutTheMotion", {"calibrate", "--log", "{log}", "--out", "{dir}/c.cal.yaml"}, 1, {"{log}", "slow pass"}},
};
// clang-format on

INSTANTIATE_TEST_SUITE_P(BadInput, CommandLineValue, ::testing::ValuesIn(kValueCases),
                         [](const auto& info) { return std::string(info.param.name); });

// ================================================================ --help

struct HelpCase {
  const char* name;
  std::vector<std::string> args;
  std::vector<std::string> lists;  ///< every option (and environment variable) the help must show
};

std::ostream& operator<<(std::ostream& os, const HelpCase& c) { return os << c.name; }

class Help : public ::testing::TestWithParam<HelpCase> {};

TEST_P(Help, ListsEveryOptionAndExits0) {
  const HelpCase& c = GetParam();
  ve::test::TempDir dir;
  const Outcome o = run_to_end(c.args, dir.path);
  ASSERT_TRUE(o.exited) << describe(o);
  EXPECT_EQ(o.code, 0) << describe(o);
  for (const auto& opt : c.lists) EXPECT_NE(o.out.find(opt), std::string::npos) << "help lacks " << opt << "\n" << o.out;
  EXPECT_NE(o.out.find("Exit codes"), std::string::npos) << o.out;
}

// clang-format off
const HelpCase kHelpCases[] = {
  {"Program", {"--help"}, {"--log-level", "--version", "run", "check", "calibrate", "monitor", "record", "evaluate",
                           "sensor-node", "FASTRTPS_DEFAULT_PROFILES_FILE", "VE_DDS_TYPE_INFORMATION", "VE_DDS_TYPE_OBJECT", "NOTIFY_SOCKET"}},
  {"Run", {"run", "--help"}, {"--config", "--domain", "--duration", "--wait-for-subscriber", "--status-period",
                              "--log-level", "FASTRTPS_DEFAULT_PROFILES_FILE", "VE_DDS_TYPE_INFORMATION",
                              "VE_DDS_TYPE_OBJECT", "NOTIFY_SOCKET", "WATCHDOG_USEC"}},
  {"Check", {"check", "--help"}, {"--config", "--log-level"}},
  {"Calibrate", {"calibrate", "--help"}, {"--config", "--axis", "--out", "--speed", "--force", "--log",
                                          "--no-reference", "--hall-delay-us", "--accel-delay-us", "--log-level"}},
  {"Monitor", {"monitor", "--help"}, {"--config", "--domain", "--duration", "--csv", "--deadline-ms", "--log-level",
                                      "FASTRTPS_DEFAULT_PROFILES_FILE", "VE_DDS_TYPE_INFORMATION", "VE_DDS_TYPE_OBJECT"}},
  {"Record", {"record", "--help"}, {"--config", "--axis", "--out", "--duration", "--first-sample-timeout", "--fast",
                                    "--log-level"}},
  {"Evaluate", {"evaluate", "--help"}, {"--config", "--axis", "--log", "--calibration", "--estimates", "--json",
                                        "--home", "--ruler-offset", "--ruler-resolution-um", "--ruler-half-window",
                                        "--log-level"}},
  {"SensorNode", {"sensor-node", "--help"}, {"--config", "--axis", "--can", "--layout", "--duration", "--drop-at",
                                             "--drop-count", "--log-level"}},
  {"HelpBeatsAMissingRequiredOption", {"record", "-h"}, {"--out", "--first-sample-timeout"}},
};
// clang-format on

INSTANTIATE_TEST_SUITE_P(BadInput, Help, ::testing::ValuesIn(kHelpCases),
                         [](const auto& info) { return std::string(info.param.name); });

TEST(BadInputCli, VersionExits0) {
  ve::test::TempDir dir;
  const Outcome o = run_to_end({"--version"}, dir.path);
  ASSERT_TRUE(o.exited) << describe(o);
  EXPECT_EQ(o.code, 0) << describe(o);
  EXPECT_FALSE(o.out.empty());
}

// A valid --log-level is taken wherever it stands.
TEST(BadInputCli, LogLevelBeforeOrAfterTheSubcommand) {
  ve::test::TempDir dir;
  for (const auto& args : {std::vector<std::string>{"--log-level", "debug", "check"},
                           std::vector<std::string>{"check", "--log-level", "warn"}}) {
    const Outcome o = run_to_end(args, dir.path);
    ASSERT_TRUE(o.exited) << describe(o);
    EXPECT_EQ(o.code, 0) << describe(o);
  }
}

// ================================================================ disk errors

struct DiskCase {
  const char* name;
  std::vector<std::string> args;
  long fsize_limit;                ///< RLIMIT_FSIZE for the child [bytes]; -1: none
  std::vector<std::string> names;  ///< what stderr must name: the path and the reason
  std::vector<std::string> absent; ///< paths that must not exist afterwards
};

std::ostream& operator<<(std::ostream& os, const DiskCase& c) { return os << c.name; }

class DiskError : public ::testing::TestWithParam<DiskCase> {};

// Exit 1, the path and the system's reason named, nothing half-written, no
// `.partial` or temporary file left, and no claim that anything was written.
TEST_P(DiskError, FailsNamingThePathAndTheReason) {
  const DiskCase& c = GetParam();
  ve::test::TempDir dir;
  write_text(dir.path / "a_file", "x\n");
  fs::create_directories(dir.path / "a_dir");
  const Outcome o = run_to_end(expand(c.args, dir.path), dir.path, c.fsize_limit);
  ASSERT_TRUE(o.exited) << describe(o);
  EXPECT_EQ(o.code, 1) << describe(o);
  for (const auto& n : expand(c.names, dir.path))
    EXPECT_NE(o.err.find(n), std::string::npos) << "stderr should name '" << n << "'\n" << describe(o);
  for (const auto& p : expand(c.absent, dir.path)) EXPECT_FALSE(fs::exists(p)) << p << " exists\n" << describe(o);
  EXPECT_TRUE(leftovers(dir.path, ".partial").empty()) << describe(o);
  EXPECT_TRUE(leftovers(dir.path, ".tmp").empty()) << describe(o);
  EXPECT_EQ(o.out.find("written to"), std::string::npos) << describe(o);
  EXPECT_EQ(o.out.find("recorded "), std::string::npos) << describe(o);
}

// clang-format off
const DiskCase kDiskCases[] = {
  {"RecordOutUnderARegularFile", {"record", "--fast", "--duration", "0.1", "--out", "{file}/r.csv"}, -1,
   {"{file}/r.csv", "Not a directory"}, {}},
  {"RecordOutInAMissingDirectory", {"record", "--fast", "--duration", "0.1", "--out", "{dir}/no/such/r.csv"}, -1,
   {"{dir}/no/such/r.csv", "No such file or directory"}, {"{dir}/no"}},
  {"RecordOutIsADirectory", {"record", "--fast", "--duration", "0.1", "--out", "{dir}/a_dir"}, -1,
   {"{dir}/a_dir", "directory"}, {}},
  {"RecordOutDevFull", {"record", "--fast", "--duration", "1", "--out", "/dev/full"}, -1,
   {"/dev/full", "No space left on device"}, {}},
  {"RecordFileSizeLimit", {"record", "--fast", "--duration", "5", "--out", "{dir}/r.csv"}, 64 * 1024,
   {"{dir}/r.csv", "File too large"}, {"{dir}/r.csv"}},
  {"RecordFileSizeLimitAtTheHeader", {"record", "--fast", "--duration", "1", "--out", "{dir}/r.csv"}, 100,
   {"{dir}/r.csv", "File too large"}, {"{dir}/r.csv"}},
  {"EvaluateEstimatesUnderARegularFile", {"evaluate", "--log", "{log}", "--estimates", "{file}/e.csv"}, -1,
   {"--estimates", "{file}/e.csv", "Not a directory"}, {}},
  {"EvaluateEstimatesInAMissingDirectory", {"evaluate", "--log", "{log}", "--estimates", "{dir}/no/e.csv"}, -1,
   {"--estimates", "{dir}/no/e.csv", "No such file or directory"}, {}},
  {"EvaluateEstimatesIsADirectory", {"evaluate", "--log", "{log}", "--estimates", "{dir}/a_dir"}, -1,
   {"--estimates", "{dir}/a_dir", "directory"}, {}},
  {"EvaluateEstimatesDevFull", {"evaluate", "--log", "{log}", "--estimates", "/dev/full"}, -1,
   {"--estimates", "/dev/full", "No space left on device"}, {}},
  {"EvaluateEstimatesFileSizeLimit", {"evaluate", "--log", "{log}", "--estimates", "{dir}/e.csv"}, 16 * 1024,
   {"--estimates", "{dir}/e.csv", "File too large"}, {"{dir}/e.csv"}},
  {"CalibrateOutUnderARegularFile", {"calibrate", "--out", "{file}/c.cal.yaml"}, -1,
   {"{file}", "Not a directory"}, {}},
  {"CalibrateOutIsADirectory", {"calibrate", "--out", "{dir}/a_dir"}, -1, {"{dir}/a_dir", "directory"}, {}},
  {"CalibrateOutIsDevFull", {"calibrate", "--out", "/dev/full"}, -1, {"/dev/full", "not a regular file"}, {}},
  {"CalibrateFileSizeLimit", {"calibrate", "--out", "{dir}/c.cal.yaml"}, 4096,
   {"{dir}/c.cal.yaml", "File too large"}, {"{dir}/c.cal.yaml"}},
};
// clang-format on

INSTANTIATE_TEST_SUITE_P(BadInput, DiskError, ::testing::ValuesIn(kDiskCases),
                         [](const auto& info) { return std::string(info.param.name); });

// A directory the program may not write into (meaningless for root, who may).
TEST(BadInputCli, UnwritableDirectoryIsNamedWithTheReason) {
  if (geteuid() == 0) GTEST_SKIP() << "running as root: no directory is unwritable by permissions";
  ve::test::TempDir dir;
  fs::create_directories(dir.path / "ro");
  fs::permissions(dir.path / "ro", fs::perms::owner_read | fs::perms::owner_exec);
  for (const auto& args :
       {std::vector<std::string>{"record", "--fast", "--duration", "0.1", "--out", (dir.path / "ro/r.csv").string()},
        std::vector<std::string>{"evaluate", "--log", inputs().short_log().string(), "--estimates",
                                 (dir.path / "ro/e.csv").string()},
        std::vector<std::string>{"calibrate", "--out", (dir.path / "ro/c.cal.yaml").string()}}) {
    const Outcome o = run_to_end(args, dir.path);
    ASSERT_TRUE(o.exited) << describe(o);
    EXPECT_EQ(o.code, 1) << describe(o);
    EXPECT_NE(o.err.find((dir.path / "ro").string()), std::string::npos) << describe(o);
    EXPECT_NE(o.err.find("Permission denied"), std::string::npos) << describe(o);
  }
  fs::permissions(dir.path / "ro", fs::perms::owner_all);
}

// ================================================================ signals

/// What each signal case starts.
enum class Phase {
  blocked_in_open,     ///< reading a FIFO nobody writes
  blocked_in_read,     ///< reading a FIFO whose writer sent a header and then nothing
  working,             ///< working through a long input, or running
};

struct SignalCase {
  const char* name;
  std::vector<std::string> args;
  Phase phase;
  int sig;
  int delay_ms;                    ///< the signal is sent this long after the start
  std::vector<int> codes;          ///< exit codes allowed
  const char* output;              ///< "" or a path ({dir}/...) that must be complete or absent
  bool output_is_raw_log;          ///< the output is a raw log: complete means every row reads
};

std::ostream& operator<<(std::ostream& os, const SignalCase& c) { return os << c.name; }

class Signal : public ::testing::TestWithParam<SignalCase> {};

TEST_P(Signal, EndsPromptlyLeavingOutputsCompleteOrAbsent) {
  const SignalCase& c = GetParam();
  ve::test::TempDir dir;
  const fs::path fifo = dir.path / "fifo";
  ASSERT_EQ(mkfifo(fifo.c_str(), 0600), 0);
  std::vector<std::string> args = expand(c.args, dir.path);
  for (auto& a : args) {
    if (a == "{gap_machine}") {
      // A paced replay whose next row is due in 1000 s: the source sleeps in read().
      std::string log = slurp(inputs().short_log());
      std::string last = log.substr(log.rfind('\n', log.size() - 2) + 1);
      log += "1000.000000000" + last.substr(last.find(','));
      write_text(dir.path / "gap.csv", log);
      write_text(dir.path / "gap.yaml", "axes:\n  - name: x\n    motor: " + std::string(VE_SOURCE_DIR) +
                                            "/config/motors/sim-12mm.yaml\n    driver: {type: replay, log: " +
                                            (dir.path / "gap.csv").string() + ", realtime: true}\n");
      a = (dir.path / "gap.yaml").string();
    }
    if (a == "{fifo}") a = fifo.string();
    if (a == "{domain}") a = std::to_string(ve::test::dds_domain());
  }
  int writer = -1;
  if (c.phase == Phase::blocked_in_read) {
    // Held open for writing by the test: the reader sees no end of file, ever.
    writer = open(fifo.c_str(), O_RDWR | O_CLOEXEC);
    ASSERT_GE(writer, 0);
    const std::string head =
        "# virtual-encoder raw log v1\nt_s,hall_0_v,hall_1_v,hall_2_v,hall_3_v,accel_mps2\n0.0,1,1,1,1,0\n";
    ASSERT_EQ(::write(writer, head.data(), head.size()), static_cast<ssize_t>(head.size()));
  }
  Child child(args);
  ASSERT_TRUE(child.started());
  // Into the phase: blocked at once, or a moment into the work.
  std::this_thread::sleep_for(std::chrono::milliseconds(c.delay_ms));
  const bool was_running = child.running();
  child.signal(c.sig);
  const Outcome o = child.wait(20s);
  if (writer >= 0) close(writer);
  std::printf("[ figures  ] %s: %s -> %s after %.0f ms%s\n", c.name, c.sig == SIGINT ? "SIGINT" : "SIGTERM",
              o.exited ? ("exit " + std::to_string(o.code)).c_str() : "no exit", o.seconds * 1e3,
              was_running ? "" : " (had ended before the signal)");
  ASSERT_FALSE(o.hung) << describe(o);
  ASSERT_TRUE(o.exited) << describe(o);
  EXPECT_NE(std::find(c.codes.begin(), c.codes.end(), o.code), c.codes.end()) << describe(o);
  if (o.code >= 128) {
    EXPECT_EQ(o.code, 128 + c.sig) << describe(o);
    EXPECT_NE(o.err.find(c.sig == SIGINT ? "SIGINT" : "SIGTERM"), std::string::npos) << describe(o);
  }
  EXPECT_TRUE(leftovers(dir.path, ".partial").empty()) << describe(o);
  EXPECT_TRUE(leftovers(dir.path, ".tmp").empty()) << describe(o);
  const std::string output = expand({c.output}, dir.path)[0];
  if (!output.empty() && fs::exists(output) && c.output_is_raw_log) {
    ve::replay::RawLogReader r;
    ASSERT_TRUE(r.open(output)) << ve::replay::to_string(r.errors());
    ve::replay::RawLogRow row;
    std::size_t rows = 0;
    ve::replay::RawLogReader::Next n;
    while ((n = r.next(row)) == ve::replay::RawLogReader::Next::row) ++rows;
    EXPECT_EQ(n, ve::replay::RawLogReader::Next::end) << ve::replay::to_string(r.errors());
    EXPECT_GT(rows, 0u);
  } else if (!output.empty() && fs::exists(output)) {
    EXPECT_EQ(o.code, 0) << output << " exists after an interrupted run\n" << describe(o);
  }
}

// clang-format off
const SignalCase kSignalCases[] = {
  {"EvaluateFifoNoWriterSigint", {"evaluate", "--log", "{fifo}", "--estimates", "{dir}/e.csv"}, Phase::blocked_in_open, SIGINT, 500, {130}, "{dir}/e.csv", false},
  {"EvaluateFifoNoWriterSigterm", {"evaluate", "--log", "{fifo}", "--estimates", "{dir}/e.csv"}, Phase::blocked_in_open, SIGTERM, 500, {143}, "{dir}/e.csv", false},
  {"EvaluateFifoEndlessSigint", {"evaluate", "--log", "{fifo}", "--estimates", "{dir}/e.csv"}, Phase::blocked_in_read, SIGINT, 500, {130}, "{dir}/e.csv", false},
  {"EvaluateFifoEndlessSigterm", {"evaluate", "--log", "{fifo}", "--estimates", "{dir}/e.csv"}, Phase::blocked_in_read, SIGTERM, 500, {143}, "{dir}/e.csv", false},
  {"EvaluateLongLogSigint", {"evaluate", "--log", "{long}", "--estimates", "{dir}/e.csv"}, Phase::working, SIGINT, 300, {0, 130}, "{dir}/e.csv", false},
  {"EvaluateLongLogSigterm", {"evaluate", "--log", "{long}", "--estimates", "{dir}/e.csv"}, Phase::working, SIGTERM, 300, {0, 143}, "{dir}/e.csv", false},
  {"CalibrateFifoNoWriterSigint", {"calibrate", "--log", "{fifo}", "--out", "{dir}/c.cal.yaml"}, Phase::blocked_in_open, SIGINT, 500, {130}, "{dir}/c.cal.yaml", false},
  {"CalibrateFifoEndlessSigterm", {"calibrate", "--log", "{fifo}", "--out", "{dir}/c.cal.yaml"}, Phase::blocked_in_read, SIGTERM, 500, {143}, "{dir}/c.cal.yaml", false},
  {"CalibrateLiveSigint", {"calibrate", "--out", "{dir}/c.cal.yaml"}, Phase::working, SIGINT, 700, {0, 130}, "{dir}/c.cal.yaml", false},
  {"CalibrateLiveSigterm", {"calibrate", "--out", "{dir}/c.cal.yaml"}, Phase::working, SIGTERM, 700, {0, 143}, "{dir}/c.cal.yaml", false},
  {"CheckFifoConfigSigint", {"check", "--config", "{fifo}"}, Phase::blocked_in_open, SIGINT, 500, {1, 2, 130}, "", false},
  {"CheckFifoConfigSigterm", {"check", "--config", "{fifo}"}, Phase::blocked_in_open, SIGTERM, 500, {1, 2, 143}, "", false},
  {"EvaluateFifoConfigSigint", {"evaluate", "--config", "{fifo}", "--log", "{log}"}, Phase::blocked_in_open, SIGINT, 500, {1, 2, 130}, "", false},
  {"RecordFifoConfigSigterm", {"record", "--config", "{fifo}", "--out", "{dir}/r.csv"}, Phase::blocked_in_open, SIGTERM, 500, {1, 2, 143}, "{dir}/r.csv", true},
  // Ending a recording on a signal is how a recording of unbounded duration ends: exit 0, the log complete.
  {"RecordRunningSigint", {"record", "--duration", "0", "--out", "{dir}/r.csv"}, Phase::working, SIGINT, 1500, {0}, "{dir}/r.csv", true},
  {"RecordRunningSigterm", {"record", "--duration", "0", "--out", "{dir}/r.csv"}, Phase::working, SIGTERM, 1500, {0}, "{dir}/r.csv", true},
  {"RecordPacedReplayAsleepSigint", {"record", "--config", "{gap_machine}", "--duration", "0", "--out", "{dir}/r.csv"}, Phase::working, SIGINT, 1500, {0}, "{dir}/r.csv", true},
  {"RunSigint", {"run", "--domain", "{domain}"}, Phase::working, SIGINT, 1500, {0}, "", false},
  {"RunSigterm", {"run", "--domain", "{domain}"}, Phase::working, SIGTERM, 1500, {0}, "", false},
  {"MonitorSigint", {"monitor", "--domain", "{domain}"}, Phase::working, SIGINT, 1500, {0}, "", false},
  {"MonitorCsvSigterm", {"monitor", "--csv", "--domain", "{domain}"}, Phase::working, SIGTERM, 1500, {0}, "", false},
  // Without SocketCAN (a container) the node fails at once (1); with it, a signal ends it (0).
  {"SensorNodeSigint", {"sensor-node", "--layout", "{src}/config/can/classic-4hall.yaml", "--can", "vcan0"}, Phase::working, SIGINT, 1500, {0, 1, 2}, "", false},
};
// clang-format on

INSTANTIATE_TEST_SUITE_P(BadInput, Signal, ::testing::ValuesIn(kSignalCases),
                         [](const auto& info) { return std::string(info.param.name); });

}  // namespace
