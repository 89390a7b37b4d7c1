// virtual-encoder: one executable, one subcommand per job.
#include <CLI/CLI.hpp>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include "commands.hpp"
#include "signals.hpp"

int main(int argc, char** argv) {
  // Before any thread exists (Fast DDS starts its own), so all inherit the mask.
  ve::app::block_termination_signals();

  CLI::App app{"Virtual Encoder: Hall sensors + accelerometer -> encoder-equivalent position and velocity over DDS"};
  app.set_version_flag("--version", std::string(VE_VERSION));
  app.require_subcommand(1);
  std::string log_level = "info";
  app.add_option("--log-level", log_level, "trace|debug|info|warn|error")->capture_default_str();

  ve::app::RunOptions run;
  int run_domain = -1;
  auto* run_cmd = app.add_subcommand("run", "Estimate and publish every axis of a machine over DDS");
  run_cmd->add_option("--config,-c", run.config, "Machine file (default: the built-in simulator machine)");
  run_cmd->add_option("--domain,-d", run_domain, "DDS domain, overrides dds.domain")->check(CLI::Range(0, 232));
  run_cmd->add_option("--duration", run.duration_s, "Stop after this many seconds (default: run until signalled)")
      ->check(CLI::NonNegativeNumber);
  run_cmd->add_option("--wait-for-subscriber", run.wait_for_subscriber_s,
                      "Wait up to this many seconds for a first subscriber before starting the sensors")
      ->check(CLI::NonNegativeNumber);
  // Test and diagnostic hook: stall one axis' loop once (the deadline tests use it).
  run_cmd->add_option("--stall-axis", run.stall_axis, "Test/diagnostic: stall this axis' loop once")->group("");
  run_cmd->add_option("--stall-after-s", run.stall_after_s)->group("");
  run_cmd->add_option("--stall-for-s", run.stall_for_s)->group("");
  run_cmd->add_option("--status-period", run.status_period_s, "Seconds between status lines")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();

  ve::app::CheckOptions check;
  auto* check_cmd = app.add_subcommand("check", "Validate a machine file, its motor files and calibrations");
  check_cmd->add_option("--config,-c", check.config, "Machine file (default: the built-in simulator machine)");

  ve::app::CalibrateOptions cal;
  auto* cal_cmd = app.add_subcommand("calibrate", "Build an axis' Hall table from a reference sweep of the simulator");
  cal_cmd->add_option("--config,-c", cal.config, "Machine file (default: the built-in simulator machine)");
  cal_cmd->add_option("--axis,-a", cal.axis, "Axis name (default: the first)");
  cal_cmd->add_option("--out,-o", cal.out, "Calibration file to write (default: the axis' calibration file)");
  cal_cmd->add_option("--speed", cal.sweep_speed_mps, "Sweep speed [m/s]")
      ->check(CLI::Range(0.005, 0.1))
      ->capture_default_str();
  cal_cmd->add_flag("--force", cal.force, "Write the calibration even when its verdict is poor");
  cal_cmd->add_option("--log", cal.log, "Calibrate from a raw log v1 (with a ref_position_m column, or see --no-reference)");
  cal_cmd->add_flag("--no-reference", cal.no_reference,
                    "Calibrate without a reference ruler (automatic when the log has no ref_position_m column)");
  cal_cmd->add_option("--hall-delay-us", cal.hall_delay_us,
                      "Without a reference: the Halls' delay from the front end's design [us]");
  cal_cmd->add_option("--accel-delay-us", cal.accel_delay_us,
                      "Without a reference: the accelerometer's delay from its data sheet [us] (instead of the Halls')");

  ve::app::MonitorOptions mon;
  int mon_domain = -1;
  auto* mon_cmd = app.add_subcommand("monitor", "Show every axis on the DDS domain live");
  mon_cmd->add_option("--config,-c", mon.config, "Machine file to take the domain and profiles from");
  mon_cmd->add_option("--domain,-d", mon_domain, "DDS domain, overrides the config")->check(CLI::Range(0, 232));
  mon_cmd->add_option("--duration", mon.duration_s, "Stop after this many seconds")->check(CLI::NonNegativeNumber);
  mon_cmd->add_flag("--csv", mon.csv, "Stream every sample as CSV on stdout instead of the live table");
  mon_cmd->add_option("--deadline-ms", mon.deadline_ms, "Requested deadline [ms] (default: twice the offered one)")
      ->check(CLI::NonNegativeNumber);

  ve::app::RecordOptions rec;
  auto* rec_cmd = app.add_subcommand("record", "Write an axis' raw sensor samples to a raw log v1 (CSV)");
  rec_cmd->add_option("--config,-c", rec.config, "Machine file (default: the built-in simulator machine)");
  rec_cmd->add_option("--axis,-a", rec.axis, "Axis name (default: the first)");
  rec_cmd->add_option("--out,-o", rec.out, "Log file to write")->required();
  rec_cmd->add_option("--duration", rec.duration_s, "Seconds to record (0: until the source ends or Ctrl-C)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  rec_cmd->add_flag("--fast", rec.fast, "Do not pace a simulated or replayed source in real time");

  ve::app::EvaluateOptions ev;
  auto* ev_cmd = app.add_subcommand("evaluate",
                                    "Run the estimator over a raw log and score it against its truth or its reference "
                                    "ruler, or check its consistency");
  ev_cmd->add_option("--config,-c", ev.config, "Machine file (default: the built-in simulator machine)");
  ev_cmd->add_option("--axis,-a", ev.axis, "Axis name (default: the first)");
  ev_cmd->add_option("--log,-l", ev.log, "Raw log v1 (with truth columns, a ref_position_m column, or neither)")
      ->required();
  ev_cmd->add_option("--calibration", ev.calibration, "Calibration file (default: the axis' own)");
  ev_cmd->add_option("--estimates", ev.estimates, "Write the estimates per sample to this CSV");
  ev_cmd->add_flag("--json", ev.json, "Print the statistics as JSON");
  ev_cmd->add_option("--home", ev.home_m, "Start-up position hint [m] (default: the axis' homing.position_m)");
  ev_cmd->add_option("--ruler-offset", ev.ruler_offset,
                     "Without truth, against ref_position_m: auto (remove the mean difference), none, or metres to "
                     "subtract from the ruler")
      ->capture_default_str();
  ev_cmd->add_option("--ruler-resolution-um", ev.ruler_resolution_um,
                     "The ruler's resolution [um] (default: the smallest step between its readings)");
  ev_cmd->add_option("--ruler-half-window", ev.ruler_half_window,
                     "Half-width of the Savitzky-Golay window that differentiates the ruler [samples]")
      ->capture_default_str();

  // ---- sensor-node: SocketCAN sensor node emulator (issue 6) ----
  ve::app::SensorNodeOptions node;
  auto* node_cmd = app.add_subcommand("sensor-node", "Emulate a CAN sensor node: send the simulated axis' samples in a frame layout");
  node_cmd->add_option("--config,-c", node.config, "Machine file with a simulated axis (default: the built-in one)");
  node_cmd->add_option("--axis,-a", node.axis, "Axis name (default: the first)");
  node_cmd->add_option("--can", node.can, "CAN interface to send on")->capture_default_str();
  node_cmd->add_option("--layout,-l", node.layout, "Frame layout file (config/can/*.yaml)")->required();
  node_cmd->add_option("--duration", node.duration_s, "Stop after this many seconds (default: until signalled)")
      ->check(CLI::NonNegativeNumber);
  node_cmd->add_option("--drop-at", node.drop_at, "Fault injection: first frame not sent");
  node_cmd->add_option("--drop-count", node.drop_count, "Fault injection: frames not sent in a row from --drop-at");
  // ---- end sensor-node ----

  CLI11_PARSE(app, argc, argv);
  // The log goes to stderr: stdout carries what a command produces (the monitor's
  // table or CSV stream, reports), which users pipe and redirect.
  spdlog::set_default_logger(spdlog::stderr_color_mt("virtual-encoder"));
  spdlog::set_level(spdlog::level::from_str(log_level));
  spdlog::set_pattern("%H:%M:%S.%e %^%-5l%$ %v");

  if (*run_cmd) {
    if (run_domain >= 0) run.domain = run_domain;
    return ve::app::run_command(run);
  }
  if (*check_cmd) return ve::app::check_command(check);
  if (*rec_cmd) return ve::app::record_command(rec);
  if (*ev_cmd) return ve::app::evaluate_command(ev);
  if (*cal_cmd) return ve::app::calibrate_command(cal);
  if (*node_cmd) return ve::app::sensor_node_command(node);  // issue 6
  if (*mon_cmd) {
    if (mon_domain >= 0) mon.domain = mon_domain;
    return ve::app::monitor_command(mon);
  }
  return 2;
}
