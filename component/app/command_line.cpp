#include "command_line.hpp"

#include <CLI/CLI.hpp>

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <sstream>

namespace ve::app {

namespace {

constexpr const char* kProgram = "virtual-encoder";
/// Longest duration any option accepts [s]: one year ("0" means "until signalled").
constexpr double kMaxDurationS = 31536000.0;

/// A number as people write it: compact, no 309-digit expansions.
std::string compact(double x) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.10g", x);
  return buf;
}

/// The text of a value as given, shortened and made printable for a message.
std::string shown(const std::string& text) {
  std::string s;
  for (char c : text.substr(0, 40)) s += (static_cast<unsigned char>(c) < 0x20 || c == 0x7f) ? '?' : c;
  if (text.size() > 40) s += "...";
  return "'" + s + "'";
}

/// Parses a whole string as a finite double.
bool parse_finite(const std::string& text, double& x, std::string& why) {
  const char* b = text.c_str();
  char* end = nullptr;
  errno = 0;
  x = std::strtod(b, &end);
  if (text.empty() || end == b || *end != '\0') {
    why = shown(text) + " is not a number";
    return false;
  }
  if (!std::isfinite(x) || errno == ERANGE) {
    if (!std::isfinite(x) || std::abs(x) > 1.0) {
      why = shown(text) + " is not a finite number";
      return false;
    }
    x = 0.0;  // underflow: as good as zero
  }
  return true;
}

/// A finite number in [lo, hi] (or (lo, hi] when lo_open) with its unit.
CLI::Validator number(double lo, double hi, const std::string& unit, bool lo_open = false) {
  const std::string range = std::string(lo_open ? "(" : "[") + compact(lo) + ", " + compact(hi) + "] " + unit;
  return CLI::Validator(
      [=](std::string& text) -> std::string {
        double x = 0.0;
        std::string why;
        if (!parse_finite(text, x, why)) return why + ": expected a finite number in " + range;
        if (x < lo || x > hi || (lo_open && x == lo)) return compact(x) + " " + unit + " is out of range " + range;
        return std::string();
      },
      range, "NUMBER");
}

/// auto | none | metres.
CLI::Validator ruler_offset() {
  return CLI::Validator(
      [](std::string& text) -> std::string {
        if (text == "auto" || text == "none") return std::string();
        double x = 0.0;
        std::string why;
        if (!parse_finite(text, x, why)) return why + ": expected auto, none or a number of metres in [-1000, 1000]";
        if (std::abs(x) > 1000.0) return compact(x) + " m is out of range [-1000, 1000] m";
        return std::string();
      },
      "auto|none|METRES", "RULER_OFFSET");
}

const char* kLogLevels = "trace|debug|info|warn|error|critical|off";

CLI::Validator log_level() {
  return CLI::Validator(
      [](std::string& text) -> std::string {
        for (const char* l : {"trace", "debug", "info", "warn", "error", "critical", "off"})
          if (text == l) return std::string();
        return shown(text) + " is not a log level: expected one of " + std::string(kLogLevels);
      },
      kLogLevels, "LEVEL");
}

std::string env_footer(const std::string& extra) {
  std::string s =
      "\nExit codes: 0 done; 1 the job failed (a problem found, a write failed; the message says which file and why);\n"
      "  2 bad command line or unusable input (a message names the option or file); 130 / 143 interrupted by\n"
      "  SIGINT / SIGTERM before the job was done (outputs are then absent, never half-written).\n";
  if (!extra.empty()) s += "Environment:\n" + extra;
  else s += "Environment: none read by this subcommand.\n";
  s += "See docs/command-line.md.";
  return s;
}

const std::string kDdsEnvironment =
    "  FASTRTPS_DEFAULT_PROFILES_FILE  Fast DDS XML profiles loaded before the machine's dds.profiles_file\n"
    "  VE_DDS_TYPE_INFORMATION=1       announce XTypes TypeInformation (off by default: Cyclone DDS 0.10 rejects it)\n"
    "  VE_DDS_TYPE_OBJECT=1            announce TypeObjects for generic tools (off by default: Fast DDS 2.9 receivers\n"
    "                                  build them on racy receive threads; see docs/dds-interface.md)\n";

/// The one-line hint after an error.
std::string usage_hint(const CLI::App* sub) {
  if (sub == nullptr)
    return std::string("usage: ") + kProgram +
           " [--log-level LEVEL] {run|check|calibrate|monitor|record|evaluate|sensor-node|eds} [OPTIONS]; '" + kProgram +
           " --help' lists them\n";
  std::string required;
  for (const CLI::Option* o : sub->get_options())
    if (o->get_required()) required += " " + o->get_name(false, false) + " " + o->get_type_name();
  return std::string("usage: ") + kProgram + " " + sub->get_name() + required + " [OPTIONS]; '" + kProgram + " " +
         sub->get_name() + " --help' lists every option\n";
}

/// Adds --log-level to `app` (the root and every subcommand, so that it may come
/// before or after the subcommand's name and is in every --help).
void add_log_level(CLI::App* app, std::string& level) {
  app->add_option("--log-level", level, "Log verbosity on stderr (default: info)")
      ->check(log_level())
      ->type_name("LEVEL");
}

constexpr const char* kMachineFileHelp = "Machine file (default: the built-in simulator machine)";

/// A subcommand of `app`, with its own --log-level.
CLI::App* add_subcommand(CLI::App& app, const std::string& name, const std::string& description,
                         std::string& log_level) {
  auto* cmd = app.add_subcommand(name, description);
  add_log_level(cmd, log_level);
  return cmd;
}

/// --config,-c FILE: the machine file.
void add_config(CLI::App* cmd, std::string& file, const std::string& help = kMachineFileHelp) {
  cmd->add_option("--config,-c", file, help)->type_name("FILE");
}

/// --config,-c FILE and --axis,-a NAME: an axis of a machine file.
void add_machine_axis(CLI::App* cmd, std::string& file, std::string& axis,
                      const std::string& help = kMachineFileHelp) {
  add_config(cmd, file, help);
  cmd->add_option("--axis,-a", axis, "Axis name (default: the first)")->type_name("NAME");
}

/// --domain,-d ID: a DDS domain [0, 232] over the machine file's (-1: not given).
void add_domain(CLI::App* cmd, int& domain, const std::string& help) {
  cmd->add_option("--domain,-d", domain, help)->check(CLI::Range(0, 232))->type_name("ID");
}

/// --duration SECONDS: how long the subcommand runs; 0: no limit.
void add_duration(CLI::App* cmd, double& seconds, const std::string& help) {
  cmd->add_option("--duration", seconds, help)
      ->check(number(0, kMaxDurationS, "s"))
      ->type_name("SECONDS")
      ->capture_default_str();
}

}  // namespace

const char* const kMonitorTableLegend =
    "Table (one row per axis, from its last sample received):\n"
    "  axis          the axis' name and, in parentheses, its DDS id ('id N' until its description arrives)\n"
    "  position[mm]  position;  vel[mm/s]  velocity\n"
    "  sx[um]        one-sigma uncertainty of the position the encoder publishes;  sv[mm/s]  the same of the velocity\n"
    "  rate[Hz]      samples received from the axis in the last second\n"
    "  dl-miss(r/o)  deadline misses: r requested, seen by this monitor (no sample within --deadline-ms) /\n"
    "                o offered, reported by the encoder since it started ('-' until its diagnostics arrive)\n"
    "  gaps          samples lost on the way, counted from gaps in the sequence numbers\n"
    "  innov         RMS of the normalised Hall innovation over the encoder's last diagnostics period (0.1 s):\n"
    "                about 1 when the Hall sensors and the filter agree, well above 1 when they do not\n"
    "  bias[m/s2]    the accelerometer bias the filter estimates now\n"
    "  step[us]      longest estimator + publish time of one sample in the last diagnostics period\n"
    "                (innov, bias and step come from the encoder's diagnostics, 10 a second; '-' until the first)\n"
    "  status        the status word's flags, '|' between them, '-' for none:\n"
    "                VALID position and velocity may be used; CAL a calibration table is in use;\n"
    "                HOMED the position is absolute on the travel; DEGRADED fewer sensors than configured;\n"
    "                FAULT a sensor is flagged; OUT_OF_TRAVEL outside the calibrated travel;\n"
    "                HALL_REJ this sample's Hall position was rejected (not used); ACC_FAULT accelerometer\n"
    "                missing or saturated; H0..H7 that Hall sensor is flagged faulty; 'waiting' (and '-' for\n"
    "                position, vel, sx and sv) until the axis' first sample arrives\n";

const char* const kMonitorCsvLegend =
    "--csv columns (one row per sample received, after a header row):\n"
    "  axis_id                the axis' DDS id\n"
    "  sequence               +1 per published sample of the axis\n"
    "  sample_time_ns         the sensor sample's instant, on the source's clock [ns]\n"
    "  status                 the status word, hex: bit 0 VALID, 1 CAL, 2 HOMED, 3 DEGRADED, 4 FAULT,\n"
    "                         5 OUT_OF_TRAVEL, 6 HALL_REJ, 7 ACC_FAULT, 16+n Hall sensor n flagged\n"
    "  position_counts        encoder-equivalent position [counts]\n"
    "  velocity_counts_per_s  encoder-equivalent velocity [counts/s]\n"
    "  position_m, velocity_mps, acceleration_mps2               the estimate in SI units\n"
    "  position_std_m, velocity_std_mps, acceleration_std_mps2   their one-sigma uncertainties\n"
    "  source_time_ns         host CLOCK_REALTIME when the driver handed the sample over [ns]\n"
    "  publish_time_ns        host CLOCK_REALTIME just before the encoder wrote it [ns]\n";

const char* subcommand_name(Subcommand c) {
  switch (c) {
    case Subcommand::run: return "run";
    case Subcommand::check: return "check";
    case Subcommand::calibrate: return "calibrate";
    case Subcommand::monitor: return "monitor";
    case Subcommand::record: return "record";
    case Subcommand::evaluate: return "evaluate";
    case Subcommand::sensor_node: return "sensor-node";
    case Subcommand::eds: return "eds";
    case Subcommand::none: break;
  }
  return "";
}

CommandLine parse_command_line(int argc, const char* const* argv) {
  CommandLine cl;
  CLI::App app{"Virtual Encoder: Hall sensors + accelerometer -> encoder-equivalent position and velocity over DDS",
               kProgram};
  app.set_version_flag("--version", std::string(VE_VERSION));
  app.require_subcommand(1);
  add_log_level(&app, cl.log_level);
  app.footer(env_footer(kDdsEnvironment + "  NOTIFY_SOCKET, WATCHDOG_USEC      systemd readiness and watchdog (run)\n"));

  // ---- run
  RunOptions& run = cl.run;
  int run_domain = -1;
  auto* run_cmd = add_subcommand(app, "run", "Estimate and publish every axis of a machine over DDS", cl.log_level);
  add_config(run_cmd, run.config);
  add_domain(run_cmd, run_domain, "DDS domain, overrides dds.domain [0, 232]");
  add_duration(run_cmd, run.duration_s, "Stop after this many seconds; 0: run until SIGINT/SIGTERM");
  run_cmd->add_option("--wait-for-subscriber", run.wait_for_subscriber_s,
                      "Wait up to this many seconds for a first subscriber before starting the sensors; 0: start at "
                      "once")
      ->check(number(0, kMaxDurationS, "s"))
      ->type_name("SECONDS")
      ->capture_default_str();
  run_cmd->add_option("--status-period", run.status_period_s, "Seconds between the status lines on the log")
      ->check(number(0.01, 86400, "s"))
      ->type_name("SECONDS")
      ->capture_default_str();
  run_cmd->footer(env_footer(kDdsEnvironment +
                             "  NOTIFY_SOCKET, WATCHDOG_USEC      systemd: readiness (Type=notify) and the watchdog\n"));

  // ---- check
  CheckOptions& check = cl.check;
  auto* check_cmd =
      add_subcommand(app, "check", "Validate a machine file, its motor files and calibrations", cl.log_level);
  add_config(check_cmd, check.config);
  check_cmd->footer(env_footer(""));

  // ---- calibrate
  CalibrateOptions& cal = cl.calibrate;
  auto* cal_cmd = add_subcommand(app, "calibrate", "Build an axis' Hall table from a reference sweep of the simulator",
                                 cl.log_level);
  add_machine_axis(cal_cmd, cal.config, cal.axis);
  cal_cmd->add_option("--out,-o", cal.out,
                      "Calibration file to write (default: the axis' calibration file); the report and plots go "
                      "beside it")
      ->type_name("FILE");
  cal_cmd->add_option("--speed", cal.sweep_speed_mps, "Sweep speed of the live simulator run")
      ->check(number(0.005, 0.1, "m/s"))
      ->type_name("M/S")
      ->capture_default_str();
  cal_cmd->add_flag("--force", cal.force, "Write the calibration even when its verdict is poor");
  auto* cal_log = cal_cmd->add_option(
      "--log", cal.log, "Calibrate from a raw log v1 (with a ref_position_m column, or see --no-reference)")
      ->type_name("FILE");
  cal_cmd->add_flag("--no-reference", cal.no_reference,
                    "Calibrate without a reference ruler (automatic when the log has no ref_position_m column)");
  auto* hall_delay = cal_cmd->add_option("--hall-delay-us", cal.hall_delay_us,
                                         "Without a reference: the Halls' delay from the front end's design")
                         ->check(number(0, 10000, "us"))
                         ->type_name("US");
  auto* accel_delay =
      cal_cmd->add_option("--accel-delay-us", cal.accel_delay_us,
                          "Without a reference: the accelerometer's delay from its data sheet (instead of the Halls')")
          ->check(number(0, 10000, "us"))
          ->type_name("US");
  hall_delay->excludes(accel_delay);
  auto* thermal = cal_cmd->add_flag(
      "--thermal", cal.thermal,
      "Thermal calibration: add each Hall sensor's temperature coefficients to the existing calibration, from a "
      "calibration run recorded 5 K or more warmer or colder (--log, or live on the simulator)");
  auto* sim_rise = cal_cmd->add_option("--sim-temperature-rise", cal.sim_temperature_rise_k,
                                       "With --thermal, live on the simulator: how much warmer its motor runs")
                       ->check(number(-40, 40, "K"))
                       ->type_name("K")
                       ->capture_default_str();
  sim_rise->needs(thermal);
  sim_rise->excludes(cal_log);
  thermal->excludes(hall_delay);
  thermal->excludes(accel_delay);
  thermal->excludes("--force");
  thermal->excludes("--no-reference");
  (void)cal_log;
  cal_cmd->footer(env_footer(""));

  // ---- monitor
  MonitorOptions& mon = cl.monitor;
  int mon_domain = -1;
  auto* mon_cmd = add_subcommand(app, "monitor", "Show every axis on the DDS domain live", cl.log_level);
  add_config(mon_cmd, mon.config, "Machine file to take the domain and profiles from");
  add_domain(mon_cmd, mon_domain, "DDS domain, overrides the config [0, 232]");
  add_duration(mon_cmd, mon.duration_s, "Stop after this many seconds; 0: until SIGINT/SIGTERM");
  mon_cmd->add_flag("--csv", mon.csv, "Stream every sample as CSV on stdout instead of the live table");
  mon_cmd->add_option("--deadline-ms", mon.deadline_ms,
                      "Requested deadline; 0: twice the offered one of the machine file")
      ->check(number(0, 3600000, "ms"))
      ->type_name("MS")
      ->capture_default_str();
  mon_cmd->footer(std::string(kMonitorTableLegend) + "\n" + kMonitorCsvLegend +
                  "\nOn a terminal the table is redrawn 4 times a second, otherwise printed once a second. A closed\n"
                  "stdout (`monitor --csv | head`) ends the monitor quietly with exit code 0.\n" +
                  env_footer(kDdsEnvironment));

  // ---- record
  RecordOptions& rec = cl.record;
  auto* rec_cmd =
      add_subcommand(app, "record", "Write an axis' raw sensor samples to a raw log v1 (CSV)", cl.log_level);
  add_machine_axis(rec_cmd, rec.config, rec.axis);
  rec_cmd->add_option("--out,-o", rec.out,
                      "Log file to write (written as FILE.partial, renamed when complete; an existing device or "
                      "FIFO such as /dev/stdout is written directly)")
      ->required()
      ->type_name("FILE");
  add_duration(rec_cmd, rec.duration_s, "Seconds of samples to record; 0: until the source ends or SIGINT/SIGTERM");
  rec_cmd->add_option("--first-sample-timeout", rec.first_sample_timeout_s,
                      "Give up (exit 1) when the source delivers no first sample within this many seconds (a live "
                      "CAN bus that is silent)")
      ->check(number(0.01, 3600, "s"))
      ->type_name("SECONDS")
      ->capture_default_str();
  rec_cmd->add_flag("--fast", rec.fast, "Do not pace a simulated or replayed source in real time");
  rec_cmd->footer(env_footer(""));

  // ---- evaluate
  EvaluateOptions& ev = cl.evaluate;
  double home_m = 0.0;
  auto* ev_cmd = add_subcommand(app, "evaluate",
                                "Run the estimator over a raw log and score it against its truth or its reference "
                                "ruler, or check its consistency",
                                cl.log_level);
  add_machine_axis(ev_cmd, ev.config, ev.axis);
  ev_cmd->add_option("--log,-l", ev.log, "Raw log v1 (with truth columns, a ref_position_m column, or neither)")
      ->required()
      ->type_name("FILE");
  ev_cmd->add_option("--calibration", ev.calibration, "Calibration file (default: the axis' own)")->type_name("FILE");
  ev_cmd->add_option("--estimates", ev.estimates,
                     "Write the estimates per sample to this CSV (written as FILE.partial, renamed when complete)")
      ->type_name("FILE");
  ev_cmd->add_flag("--json", ev.json, "Print the statistics as JSON");
  auto* home = ev_cmd->add_option("--home", home_m,
                                  "Start-up position hint [m], inside the axis' travel (default: its homing.position_m)")
                   ->check(number(-1e6, 1e6, "m"))
                   ->type_name("METRES");
  ev_cmd->add_option("--ruler-offset", ev.ruler_offset,
                     "Without truth, against ref_position_m: auto (remove the mean difference), none, or metres to "
                     "subtract from the ruler")
      ->check(ruler_offset())
      ->type_name("OFFSET")
      ->capture_default_str();
  ev_cmd->add_option("--ruler-resolution-um", ev.ruler_resolution_um,
                     "The ruler's resolution; 0: the smallest step between its readings")
      ->check(number(0, 1e6, "um"))
      ->type_name("UM")
      ->capture_default_str();
  ev_cmd->add_option("--ruler-half-window", ev.ruler_half_window,
                     "Half-width of the Savitzky-Golay window that differentiates the ruler [1, 10000] samples")
      ->check(CLI::Range(1, 10000))
      ->type_name("SAMPLES")
      ->capture_default_str();
  ev_cmd->footer(env_footer(""));

  // ---- sensor-node
  SensorNodeOptions& node = cl.sensor_node;
  auto* node_cmd = add_subcommand(app, "sensor-node",
                                  "Emulate a CAN sensor node: send the simulated axis' samples in a frame layout",
                                  cl.log_level);
  add_machine_axis(node_cmd, node.config, node.axis,
                   "Machine file with a simulated axis (default: the built-in one)");
  node_cmd->add_option("--can", node.can, "CAN interface to send on")->type_name("IFACE")->capture_default_str();
  node_cmd->add_option("--layout,-l", node.layout, "Frame layout file (config/can/*.yaml)")
      ->required()
      ->type_name("FILE");
  add_duration(node_cmd, node.duration_s, "Stop after this many seconds; 0: until SIGINT/SIGTERM");
  node_cmd->add_option("--drop-at", node.drop_at, "Fault injection: first frame (counter) not sent")
      ->check(number(0, 1e15, "frames"))
      ->type_name("FRAME");
  node_cmd->add_option("--drop-count", node.drop_count, "Fault injection: frames not sent in a row from --drop-at")
      ->check(number(0, 1e15, "frames"))
      ->type_name("FRAMES");
  node_cmd->footer(env_footer(""));

  // ---- eds
  EdsOptions& eds = cl.eds;
  auto* eds_cmd = add_subcommand(app, "eds", "Write the EDS (CiA 306) of an axis' CANopen node for a master's configuration tool",
                                 cl.log_level);
  add_machine_axis(eds_cmd, eds.config, eds.axis, "Machine file whose axis has a canopen: block (default: the built-in one)");
  eds_cmd->add_option("--out,-o", eds.out, "EDS file to write (default: standard output)")->type_name("FILE");
  eds_cmd->footer(env_footer(""));

  CLI::App* failed_in = nullptr;
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    for (CLI::App* sub : {run_cmd, check_cmd, cal_cmd, mon_cmd, rec_cmd, ev_cmd, node_cmd, eds_cmd})
      if (sub->parsed()) failed_in = sub;
    const std::string name = e.get_name();
    if (name == "CallForHelp" || name == "CallForAllHelp") {
      cl.out = name == "CallForAllHelp" ? app.help("", CLI::AppFormatMode::All) : app.help();
      cl.exit_code = kExitOk;
      return cl;
    }
    if (name == "CallForVersion") {
      cl.out = std::string(e.what()) + "\n";
      cl.exit_code = kExitOk;
      return cl;
    }
    std::string what = e.what();
    if (failed_in == nullptr) {
      // Name the word that is not a subcommand (CLI11 only says one is required).
      for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i] != nullptr ? argv[i] : "";
        if (a == "--log-level") {
          ++i;
          continue;
        }
        if (a.empty() || a[0] == '-') continue;
        what = "unknown subcommand " + shown(a);
        break;
      }
    }
    cl.err = std::string(kProgram) + (failed_in ? std::string(" ") + failed_in->get_name() : std::string()) + ": " +
             what + "\n" + usage_hint(failed_in);
    cl.exit_code = kExitUsage;
    return cl;
  } catch (const std::exception& e) {
    // CLI11 reports everything as ParseError; anything else is a bug, still not a crash.
    cl.err = std::string(kProgram) + ": " + e.what() + "\n" + usage_hint(nullptr);
    cl.exit_code = kExitUsage;
    return cl;
  }

  if (*run_cmd) {
    if (run_domain >= 0) run.domain = run_domain;
    cl.command = Subcommand::run;
  } else if (*check_cmd) {
    cl.command = Subcommand::check;
  } else if (*cal_cmd) {
    cl.command = Subcommand::calibrate;
  } else if (*mon_cmd) {
    if (mon_domain >= 0) mon.domain = mon_domain;
    cl.command = Subcommand::monitor;
  } else if (*rec_cmd) {
    cl.command = Subcommand::record;
  } else if (*ev_cmd) {
    if (home->count() > 0) ev.home_m = home_m;
    cl.command = Subcommand::evaluate;
  } else if (*node_cmd) {
    cl.command = Subcommand::sensor_node;
  } else if (*eds_cmd) {
    cl.command = Subcommand::eds;
  } else {
    cl.err = std::string(kProgram) + ": a subcommand is required\n" + usage_hint(nullptr);
    cl.exit_code = kExitUsage;
  }
  return cl;
}

}  // namespace ve::app
