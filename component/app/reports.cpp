#include "reports.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>

namespace ve::app {

std::string format_identification_report(const config::AxisConfig& axis, const core::Calibration& cal,
                                         const core::IdentificationReport& r) {
  std::string out;
  char buf[512];
  auto line = [&](const char* format, auto... args) {
    std::snprintf(buf, sizeof buf, format, args...);
    out += buf;
  };
  line("Calibration of axis '%s', motor %s (%d Halls, pitch %.3f mm), method %s\n", axis.name.c_str(),
       cal.info.motor.c_str(), cal.info.hall_count, cal.info.magnet_pitch_m * 1e3, cal.info.method.c_str());
  line("  created %s, id %s\n", cal.info.created_utc.c_str(), cal.info.id.c_str());
  line("Sweep (table, Hall delay)\n");
  line("  %d forward + %d backward samples at %.1f mm/s; table %d nodes x %d sensors, step %.1f um\n",
       r.sweep_forward_samples, r.sweep_backward_samples, r.sweep_speed_mps * 1e3, cal.table.points,
       cal.table.sensors, cal.table.step_m * 1e6);
  line("  forward and backward tables differ by %.3f um -> Hall delay %.2f us\n", r.forward_backward_shift_um,
       r.hall_delay_s * 1e6);
  line("  readings about the table: %.3f mV RMS\n", r.table_residual_mv);
  line("Fast motion (coil field, accelerometer)\n");
  line("  %d samples with |a| >= 1 m/s^2, up to %.1f m/s^2\n", r.dynamic_samples, r.dynamic_max_accel_mps2);
  line("  coil field: %.3f mV per m/s^2 (common mode on all Halls)\n", r.coil_field_v_per_mps2 * 1e3);
  line("  accelerometer%s: scale %.5f, bias %+.4f m/s^2, delay %.1f us, fit residual %.4f m/s^2 RMS\n",
       r.frame_accelerometer_used ? " (minus the frame accelerometer)" : "", r.accel_scale, r.accel_bias_mps2,
       r.accel_delay_s * 1e6, r.accel_fit_residual_mps2);
  line("  Hall position vs reference in fast motion: %.3f um RMS compensated (%.3f um without)\n",
       r.position_residual_um, r.position_residual_uncompensated_um);
  line("Verdict: %s\n", r.good ? "GOOD" : "POOR");
  for (const auto& p : r.problems) line("  - %s\n", p.c_str());
  return out;
}

bool write_text_file_atomic(const std::string& path, const std::string& text, std::string& error) {
  namespace fs = std::filesystem;
  const fs::path target(path);
  const fs::path dir = target.has_parent_path() ? target.parent_path() : fs::path(".");
  std::string tmpl = (dir / ("." + target.filename().string() + ".XXXXXX")).string();
  const int fd = mkstemp(tmpl.data());
  if (fd < 0) {
    error = std::strerror(errno);
    return false;
  }
  const char* p = text.data();
  std::size_t left = text.size();
  bool ok = true;
  while (left > 0 && ok) {
    const ssize_t n = ::write(fd, p, left);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      ok = false;
      break;
    }
    p += n;
    left -= static_cast<std::size_t>(n);
  }
  ok = ok && ::fchmod(fd, 0644) == 0 && ::fsync(fd) == 0;
  ok = (::close(fd) == 0) && ok;
  if (!ok || std::rename(tmpl.c_str(), path.c_str()) != 0) {
    error = std::strerror(errno);
    std::remove(tmpl.c_str());
    return false;
  }
  const int dfd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY);
  if (dfd >= 0) {
    ::fsync(dfd);
    ::close(dfd);
  }
  return true;
}

}  // namespace ve::app
