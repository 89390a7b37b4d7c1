// Fuzz target: the command line (app/command_line.hpp). The input is split at NUL
// bytes into arguments after the program name. Whatever they are, parsing returns
// (no exception, no crash), an error exits 2 with a message and a usage line, help
// and version exit 0, and every value a subcommand receives is finite and in the
// range its option states.
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <string>
#include <vector>

#include "app/command_line.hpp"

namespace {

void require(bool ok) {
  if (!ok) std::abort();
}

bool in(double x, double lo, double hi) { return std::isfinite(x) && x >= lo && x <= hi; }

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  std::vector<std::string> args{"virtual-encoder"};
  std::string cur;
  for (std::size_t i = 0; i < size && args.size() < 64; ++i) {
    if (data[i] == 0) {
      args.push_back(cur);
      cur.clear();
    } else {
      cur += static_cast<char>(data[i]);
    }
  }
  if (!cur.empty()) args.push_back(cur);
  std::vector<const char*> argv;
  for (const auto& a : args) argv.push_back(a.c_str());
  argv.push_back(nullptr);

  const ve::app::CommandLine cl = ve::app::parse_command_line(static_cast<int>(args.size()), argv.data());
  using ve::app::Subcommand;
  if (cl.command == Subcommand::none) {
    require(cl.exit_code == ve::app::kExitOk || cl.exit_code == ve::app::kExitUsage);
    if (cl.exit_code == ve::app::kExitUsage) {
      require(!cl.err.empty() && cl.err.find("usage: virtual-encoder") != std::string::npos);
      require(cl.out.empty());
    } else {
      require(!cl.out.empty() && cl.err.empty());
    }
    return 0;
  }
  require(cl.exit_code == ve::app::kExitOk && cl.err.empty());
  const std::string& l = cl.log_level;
  require(l == "trace" || l == "debug" || l == "info" || l == "warn" || l == "error" || l == "critical" ||
          l == "off");
  constexpr double kYear = 31536000.0;
  switch (cl.command) {
    case Subcommand::run:
      require(in(cl.run.duration_s, 0, kYear) && in(cl.run.wait_for_subscriber_s, 0, kYear));
      require(in(cl.run.status_period_s, 0.01, 86400));
      require(!cl.run.domain || (*cl.run.domain >= 0 && *cl.run.domain <= 232));
      break;
    case Subcommand::calibrate:
      require(in(cl.calibrate.sweep_speed_mps, 0.005, 0.1));
      require(std::isnan(cl.calibrate.hall_delay_us) || in(cl.calibrate.hall_delay_us, 0, 10000));
      require(std::isnan(cl.calibrate.accel_delay_us) || in(cl.calibrate.accel_delay_us, 0, 10000));
      require(std::isnan(cl.calibrate.hall_delay_us) || std::isnan(cl.calibrate.accel_delay_us));
      break;
    case Subcommand::monitor:
      require(in(cl.monitor.duration_s, 0, kYear) && in(cl.monitor.deadline_ms, 0, 3600000));
      require(!cl.monitor.domain || (*cl.monitor.domain >= 0 && *cl.monitor.domain <= 232));
      break;
    case Subcommand::record:
      require(in(cl.record.duration_s, 0, kYear) && in(cl.record.first_sample_timeout_s, 0.01, 3600));
      break;
    case Subcommand::evaluate: {
      require(in(cl.evaluate.ruler_resolution_um, 0, 1e6));
      require(cl.evaluate.ruler_half_window >= 1 && cl.evaluate.ruler_half_window <= 10000);
      require(!cl.evaluate.home_m || in(*cl.evaluate.home_m, -1e6, 1e6));
      const std::string& o = cl.evaluate.ruler_offset;
      if (o != "auto" && o != "none") {
        char* end = nullptr;
        const double x = std::strtod(o.c_str(), &end);
        require(!o.empty() && *end == '\0' && in(x, -1000, 1000));
      }
      break;
    }
    case Subcommand::sensor_node:
      require(in(cl.sensor_node.duration_s, 0, kYear));
      require(cl.sensor_node.drop_at <= 1000000000000000ULL && cl.sensor_node.drop_count <= 1000000000000000ULL);
      break;
    case Subcommand::check:
    case Subcommand::eds:  // strings only
    case Subcommand::none: break;
  }
  return 0;
}
