// The command line of `virtual-encoder`, parsed and checked without running
// anything: which subcommand, its options, and every value checked for what it
// means (finite, in range, with its unit). What depends on the machine file (an
// axis name, a home inside the travel) is checked by the subcommand once the file
// is loaded. docs/command-line.md describes every option.
#pragma once

#include <string>

#include "commands.hpp"

namespace ve::app {

enum class Subcommand { none, run, check, calibrate, monitor, record, evaluate, sensor_node, eds };

/// Exit codes of every subcommand (docs/command-line.md).
inline constexpr int kExitOk = 0;
inline constexpr int kExitFailed = 1;     ///< the job failed (check found problems, a write failed, ...)
inline constexpr int kExitUsage = 2;      ///< bad command line or unusable input
inline constexpr int kExitSignalBase = 128;  ///< interrupted before the job was done: 128 + the signal (130, 143)

struct CommandLine {
  /// none: nothing to run; print `out` / `err` and exit with `exit_code`
  /// (0 after --help or --version, kExitUsage after an error).
  Subcommand command = Subcommand::none;
  int exit_code = kExitOk;
  std::string out;  ///< for stdout (help, version)
  std::string err;  ///< for stderr: the error, then a one-line usage hint

  std::string log_level = "info";  ///< trace|debug|info|warn|error|critical|off, checked
  RunOptions run;
  CheckOptions check;
  CalibrateOptions calibrate;
  MonitorOptions monitor;
  RecordOptions record;
  EvaluateOptions evaluate;
  SensorNodeOptions sensor_node;
  EdsOptions eds;
};

/// Parses argv (argv[0] is the program). Never throws, never prints, never exits.
CommandLine parse_command_line(int argc, const char* const* argv);

/// The name a subcommand has on the command line ("" for none).
const char* subcommand_name(Subcommand c);

/// What every column and status flag of `monitor`'s table means: in `monitor --help`, and
/// printed by `monitor` above its first table (on a terminal, below every redraw).
extern const char* const kMonitorTableLegend;
/// What every column of `monitor --csv` means (in `monitor --help`).
extern const char* const kMonitorCsvLegend;

}  // namespace ve::app
