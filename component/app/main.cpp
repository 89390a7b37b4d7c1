// virtual-encoder: one executable, one subcommand per job.
#include <signal.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include <cstdio>

#include "command_line.hpp"
#include "commands.hpp"
#include "signals.hpp"

int main(int argc, char** argv) {
  // Before any thread exists (Fast DDS starts its own), so all inherit the mask.
  ve::app::block_termination_signals();
  // A write beyond RLIMIT_FSIZE fails with EFBIG (and is reported with the file's
  // name) instead of killing the process.
  ::signal(SIGXFSZ, SIG_IGN);

  const ve::app::CommandLine cl = ve::app::parse_command_line(argc, argv);
  if (cl.command == ve::app::Subcommand::none) {
    std::fputs(cl.out.c_str(), stdout);
    std::fputs(cl.err.c_str(), stderr);
    return cl.exit_code;
  }
  ve::app::start_termination_watcher();

  // The log goes to stderr: stdout carries what a command produces (the monitor's
  // table or CSV stream, reports), which users pipe and redirect.
  spdlog::set_default_logger(spdlog::stderr_color_mt("virtual-encoder"));
  spdlog::set_level(spdlog::level::from_str(cl.log_level));
  spdlog::set_pattern("%H:%M:%S.%e %^%-5l%$ %v");

  switch (cl.command) {
    case ve::app::Subcommand::run: return ve::app::run_command(cl.run);
    case ve::app::Subcommand::check: return ve::app::check_command(cl.check);
    case ve::app::Subcommand::calibrate: return ve::app::calibrate_command(cl.calibrate);
    case ve::app::Subcommand::monitor: return ve::app::monitor_command(cl.monitor);
    case ve::app::Subcommand::record: return ve::app::record_command(cl.record);
    case ve::app::Subcommand::evaluate: return ve::app::evaluate_command(cl.evaluate);
    case ve::app::Subcommand::sensor_node: return ve::app::sensor_node_command(cl.sensor_node);
    case ve::app::Subcommand::eds: return ve::app::eds_command(cl.eds);
    case ve::app::Subcommand::none: break;
  }
  return ve::app::kExitUsage;
}
