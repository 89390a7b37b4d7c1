#include "reports.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <limits>

#include "svg_plot.hpp"

namespace ve::app {

std::string format_identification_report(const config::AxisConfig& axis, const core::Calibration& cal,
                                         const core::IdentificationReport& r, const std::vector<std::string>& plots,
                                         const core::SelfCalibrationReport* self) {
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
  line("  the table's own noise at a node: %.3f mV (half what is left of the forward and backward tables' difference "
       "beyond the delay); where the carriage stands it repeats, and sigma holds it\n",
       r.table_noise_mv);
  line("Fast motion (coil field, accelerometer)\n");
  if (r.fast_hall_delay_std_s > 0.0)
    line("  Hall positions against the reference, regressed on velocity: Hall delay %.3f us +- %.3f us (1 sigma); %s\n",
         r.fast_hall_delay_s * 1e6, r.fast_hall_delay_std_s * 1e6,
         r.hall_delay_from_fast_motion ? "the calibration uses it (the sweep's agrees within 1 us)"
                                       : "NOT used: it disagrees with the sweep's (see the problems)");
  line("  %d samples with |a| >= 1 m/s^2, up to %.1f m/s^2\n", r.dynamic_samples, r.dynamic_max_accel_mps2);
  if (std::isfinite(r.coil_field_std_v_per_mps2))
    line("  coil field: %.4f mV per m/s^2 +- %.4f (1 sigma; common mode on all Halls)\n", r.coil_field_v_per_mps2 * 1e3,
         r.coil_field_std_v_per_mps2 * 1e3);
  else
    line("  coil field: %.3f mV per m/s^2 (common mode on all Halls)\n", r.coil_field_v_per_mps2 * 1e3);
  if (std::isfinite(r.accel_delay_std_s) && r.accel_delay_std_s > 0.0)
    line("  accelerometer%s: scale %.5f, bias %+.4f m/s^2, delay %.1f us +- %.1f us (1 sigma), fit residual %.4f m/s^2 "
         "RMS\n",
         r.frame_accelerometer_used ? " (minus the frame accelerometer)" : "", r.accel_scale, r.accel_bias_mps2,
         r.accel_delay_s * 1e6, r.accel_delay_std_s * 1e6, r.accel_fit_residual_mps2);
  else
    line("  accelerometer%s: scale %.5f, bias %+.4f m/s^2, delay %.1f us, fit residual %.4f m/s^2 RMS\n",
         r.frame_accelerometer_used ? " (minus the frame accelerometer)" : "", r.accel_scale, r.accel_bias_mps2,
         r.accel_delay_s * 1e6, r.accel_fit_residual_mps2);
  line("  Hall position vs %s in fast motion: %.3f um RMS compensated (%.3f um without); "
       "the fixes' own noise %.3f um RMS, beyond it %.3f um\n",
       self != nullptr ? "the self-made estimate (made of them: a consistency figure, not judged)" : "reference",
       r.position_residual_um,
       r.position_residual_uncompensated_um, r.position_noise_um, r.position_residual_beyond_noise_um);
  if (self != nullptr) {
    const auto& s = *self;
    line("Without a reference (the Halls, the accelerometer and the nominal pitch)\n");
    line("  position 0: %s\n", s.zero_definition.c_str());
    line("  the scale is the nominal pitch averaged over the travel\n");
    line("  slow passes: %d forward at %.3f mm/s, %d backward at %.3f mm/s; swept %.4f mm = %d whole periods\n",
         s.passes_forward, s.forward_speed_mps * 1e3, s.passes_backward, s.backward_speed_mps * 1e3, s.swept_m * 1e3,
         s.periods);
    line("  passes vs Hall positions: %.3f um RMS along the passes, %.3f um RMS where they join\n",
         s.pass_line_residual_m * 1e6, s.join_mismatch_m * 1e6);
    line("  Hall delay %.2f us: %s (forward/backward against the estimate reproduce %.2f us)\n",
         r.hall_delay_s * 1e6, s.hall_delay_source.c_str(), s.hall_delay_reproduced_s * 1e6);
    if (!s.period_pitch_m.empty()) {
      double lo = s.period_pitch_m.front(), hi = lo, sum = 0.0;
      for (double p : s.period_pitch_m) lo = std::min(lo, p), hi = std::max(hi, p), sum += p;
      line("  magnet periods (sensor 0): %zu, pitch %.4f mm mean, %.4f .. %.4f mm\n", s.period_pitch_m.size(),
           sum / s.period_pitch_m.size() * 1e3, lo * 1e3, hi * 1e3);
      line("  the track's scale is good to %.2f ppm (1 sigma): magnets placed to %.1f um, so the position may be off "
           "by %.2f um per 100 mm from home, which sigma includes; a ruler (or one known length) removes it\n",
           s.track_scale_std * 1e6, s.magnet_placement_std_m * 1e6, s.track_scale_std * 0.1 * 1e6);
    }
    std::string geo;
    for (std::size_t i = 0; i < s.sensor_offset_m.size(); ++i) {
      std::snprintf(buf, sizeof buf, "%s%.4f", i ? ", " : "", s.sensor_offset_m[i] * 1e3);
      geo += buf;
    }
    line("  sensor positions relative to sensor 0: %s mm\n", geo.c_str());
    if (cal.model.trusted_span_known())
      line("  the slow passes made the table from %.3f to %.3f mm; beyond, where the carriage turned, it rests on the "
           "accelerometer's bridges and is good to %.1f um (1 sigma, the worst quarter pitch): sigma includes it and "
           "the position is never VALID there (a ruler, or slow passes reaching further, removes it)\n",
           cal.model.table_trusted_from_m * 1e3, cal.model.table_trusted_to_m * 1e3,
           cal.model.table_outside_std_m * 1e6);
    line("  iterations: %zu, the last moved the estimate %.3f um RMS (%s)\n", s.iterations.size(),
         s.last_change_m * 1e6,
         s.converged ? "settled"
         : s.stalled ? "settled into going back and forth below the tolerated limit: further iterations would not "
                       "change the result"
                     : "going back and forth, not settled");
  }
  if (!plots.empty()) {
    line("Plots (SVG, beside this report)\n");
    for (const auto& p : plots) line("  %s\n", std::filesystem::path(p).filename().c_str());
  }
  line("Verdict: %s\n", r.good ? "GOOD" : "POOR");
  for (const auto& p : r.problems) line("  - %s\n", p.c_str());
  return out;
}

std::vector<std::string> write_calibration_plots(const std::string& calibration_path, const core::Calibration& cal,
                                                 const core::IdentificationReport& r, std::string& error) {
  std::vector<std::string> written;
  const core::HallTable& t = cal.table;
  const double pitch = cal.info.magnet_pitch_m > 0.0 ? cal.info.magnet_pitch_m : 0.012;
  const std::string id = cal.info.motor + ", calibration " + cal.info.id + " (" + cal.info.method + ")";
  auto save = [&](const char* name, const SvgPlot& plot) {
    const std::string path = calibration_path + "." + name + ".svg";
    std::string why;
    if (write_text_file_atomic(path, render_svg(plot), why))
      written.push_back(path);
    else
      error += (error.empty() ? "" : "; ") + path + ": " + why;
  };
  const int per_pitch = t.step_m > 0.0 ? static_cast<int>(std::lround(pitch / t.step_m)) : 0;
  const int periods = per_pitch > 0 ? (t.points - 1) / per_pitch : 0;

  if (t.valid() && periods > 0) {
    // One period in the middle of the travel.
    SvgPlot one;
    const int p0 = periods / 2;
    one.title = "Hall table over one magnet period (period " + std::to_string(p0 + 1) + " of " +
                std::to_string(periods) + ") - " + id;
    one.x_label = "position in the period [mm] (period starts at " +
                  std::to_string(static_cast<int>(std::lround((t.start_m + p0 * per_pitch * t.step_m) * 1e3))) + " mm)";
    one.y_label = "Hall output [V]";
    for (int s = 0; s < t.sensors; ++s) {
      SvgSeries series;
      series.label = "sensor " + std::to_string(s);
      series.color = svg_color(s);
      for (int k = 0; k <= per_pitch; ++k) {
        series.x.push_back(k * t.step_m * 1e3);
        series.y.push_back(t.v[static_cast<std::size_t>(s) * t.points + p0 * per_pitch + k]);
      }
      one.series.push_back(std::move(series));
    }
    save("table-period", one);

    // Every period folded onto one: the spread is each magnet's own signature.
    SvgPlot all;
    all.title = "Hall table, all " + std::to_string(periods) + " periods folded onto one - " + id;
    all.x_label = "position modulo the pitch [mm]";
    all.y_label = "Hall output [V]";
    const int stride = std::max(1, per_pitch / 64);
    for (int s = 0; s < t.sensors; ++s)
      for (int p = 0; p < periods; ++p) {
        SvgSeries series;
        if (p == 0) series.label = "sensor " + std::to_string(s);
        series.color = svg_color(s);
        series.width = 0.8;
        series.opacity = 0.35;
        for (int k = 0; k <= per_pitch; k += stride) {
          series.x.push_back(k * t.step_m * 1e3);
          series.y.push_back(t.v[static_cast<std::size_t>(s) * t.points + p * per_pitch + k]);
        }
        all.series.push_back(std::move(series));
      }
    save("table-all-periods", all);
  }

  const auto& c = r.curves;
  if (!c.position_m.empty()) {
    std::vector<double> x_mm;
    for (double x : c.position_m) x_mm.push_back(x * 1e3);
    // A curve binned over the position, its summary as a horizontal line.
    const auto binned = [&](const std::string& title, const std::string& y_label, int color,
                            const std::vector<double>& y, double summary, const char* summary_label) {
      SvgPlot plot;
      plot.title = title + " - " + id;
      plot.x_label = "position [mm]";
      plot.y_label = y_label;
      plot.series.push_back({"per " + std::to_string(static_cast<int>(std::lround(c.bin_m * 1e3))) + " mm",
                             svg_color(color), x_mm, y, 1.3, 1.0});
      plot.hlines.emplace_back(summary, summary_label);
      return plot;
    };
    if (c.residual_mv.size() == x_mm.size()) {
      char label[96];
      std::snprintf(label, sizeof label, "overall %.3f mV", r.table_residual_mv);
      save("residuals", binned("Readings about the table during the sweep", "RMS reading minus table [mV]", 0,
                               c.residual_mv, r.table_residual_mv, label));
    }
    if (c.forward_backward_um.size() == x_mm.size()) {
      char label[128];
      std::snprintf(label, sizeof label, "mean %.3f um = 2 v d: Hall delay %.2f us", r.forward_backward_shift_um,
                    r.hall_delay_s * 1e6);
      SvgPlot fb = binned("Forward minus backward pass", "table shift forward - backward [um]", 1,
                          c.forward_backward_um, r.forward_backward_shift_um, label);
      fb.hlines.emplace_back(0.0, "0");
      save("forward-backward", fb);
    }
  }
  return written;
}

}  // namespace ve::app
