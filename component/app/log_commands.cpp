// `record` writes raw log v1 from any driver; `evaluate` runs the estimator
// causally over a log and scores it against the log's truth, else its reference
// ruler, else reports how consistent the estimator was with itself.
#include <fmt/printf.h>
#include <signal.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <string>
#include <vector>

#include "axis.hpp"
#include "commands.hpp"
#include "config/atomic_file.hpp"
#include "config/calibration_file.hpp"
#include "config/loader.hpp"
#include "core/error_stats.hpp"
#include "core/identification.hpp"
#include "core/pipeline.hpp"
#include "core/status.hpp"
#include "replay/raw_log.hpp"
#include "replay/replay_source.hpp"
#include "reports.hpp"
#include "signals.hpp"

namespace ve::app {

namespace {

bool load(const std::string& path, config::MachineConfig& out) {
  auto result = path.empty() ? config::load_embedded_default() : config::load_machine_file(path);
  for (const auto& e : result.errors) std::fprintf(stderr, "%s\n", e.to_string().c_str());
  if (!result.ok()) return false;
  out = std::move(result.config);
  return true;
}

const config::AxisConfig* axis_named(const config::MachineConfig& m, const std::string& name) {
  if (name.empty()) return m.axes.empty() ? nullptr : &m.axes.front();
  for (const auto& a : m.axes)
    if (a.name == name) return &a;
  return nullptr;
}

/// The machine file (or the built-in machine) into `machine`, and its axis named
/// `name` (the first when empty); null, with the reason on stderr, when either fails.
const config::AxisConfig* load_axis(const std::string& path, const std::string& name,
                                    config::MachineConfig& machine) {
  if (!load(path, machine)) return nullptr;
  const config::AxisConfig* axis = axis_named(machine, name);
  if (axis == nullptr) std::fprintf(stderr, "no axis '%s' in %s\n", name.c_str(), machine.source.c_str());
  return axis;
}

}  // namespace

int record_command(const RecordOptions& options) {
  config::MachineConfig machine;
  const config::AxisConfig* axis = load_axis(options.config, options.axis, machine);
  if (axis == nullptr) return 2;
  std::string error;
  auto source = make_source(*axis, options.fast ? SourceTiming::as_fast_as_possible : SourceTiming::as_configured, error);
  if (!source) {
    std::fprintf(stderr, "%s\n", axis_error(axis->name, error).c_str());
    return 2;
  }
  // A signal also wakes a read() that sleeps until a far-off sample is due (a paced
  // replay with a gap in time), so that the recording ends cleanly at once.
  TerminationCallback wake([&source] { source->stop(); });
  // The first sample tells which optional columns the source fills.
  core::RawSample s;
  // A live source (a CAN bus) may take a moment to deliver its first sample.
  const auto first_deadline =
      std::chrono::steady_clock::now() + std::chrono::duration<double>(options.first_sample_timeout_s);
  auto st = source->read(s);
  while (st == drivers::ReadStatus::timeout && !termination_requested() &&
         std::chrono::steady_clock::now() < first_deadline)
    st = source->read(s);
  if (termination_requested()) {
    std::fprintf(stderr, "record: interrupted by %s before the first sample: nothing written\n",
                 termination_signal() == SIGTERM ? "SIGTERM" : "SIGINT");
    return interrupted_exit_code();
  }
  if (st == drivers::ReadStatus::timeout) {
    std::fprintf(stderr, "the source gave no sample within %g s (--first-sample-timeout): nothing written to %s\n",
                 options.first_sample_timeout_s, options.out.c_str());
    return 1;
  }
  if (st != drivers::ReadStatus::ok) {
    std::fprintf(stderr, "the source gave no sample%s%s: nothing written to %s\n",
                 source->last_error().empty() ? "" : ": ", source->last_error().c_str(), options.out.c_str());
    return 1;
  }
  double reference = 0.0;
  replay::RawLogWriter::Columns cols;
  cols.hall_count = axis->motor.hall.count;
  cols.accel_base = s.accel_base_valid;
  cols.temperature = s.temperature_valid;
  cols.reference = source->reference_position(reference);
  cols.truth = source->truth() != nullptr;
  char rate[32];
  std::snprintf(rate, sizeof rate, "%g", axis->motor.sample_rate_hz);
  replay::RawLogWriter writer;
  if (!writer.open(options.out, cols,
                   {{"sample_rate_hz", rate},
                    {"motor", axis->motor.name},
                    {"machine", machine.name},
                    {"axis", axis->name},
                    {"source", source->describe()}},
                   error)) {
    std::fprintf(stderr, "cannot write %s: %s\n", options.out.c_str(), error.c_str());
    return 1;
  }
  // An interrupted recording leaves no PATH.partial behind (a signal ends it cleanly;
  // a forced end removes it).
  if (!writer.direct()) config::register_scratch_file(writer.partial_path());
  auto give_up = [&] {
    writer.discard();
    config::unregister_scratch_file(writer.partial_path());
  };
  const std::int64_t t0 = s.t_ns;
  const bool tty = isatty(STDERR_FILENO);
  std::uint64_t n = 0;
  int code = 0;
  auto last_check = std::chrono::steady_clock::now();
  while (st == drivers::ReadStatus::ok) {
    const bool has_ref = cols.reference && source->reference_position(reference);
    if (!writer.write(s, cols.truth ? source->truth() : nullptr, has_ref ? &reference : nullptr)) {
      std::fprintf(stderr, "\nrecording failed: %s; nothing written to %s\n", writer.error().c_str(),
                   options.out.c_str());
      give_up();
      return 1;
    }
    ++n;
    if (options.duration_s > 0 && static_cast<double>(s.t_ns - t0) * 1e-9 >= options.duration_s) break;
    // Ctrl-C ends the recording cleanly; checked a few times a second, not per sample.
    const auto now = std::chrono::steady_clock::now();
    if (now - last_check > std::chrono::milliseconds(200)) {
      last_check = now;
      if (termination_requested()) break;
      if (tty) std::fprintf(stderr, "\rrecording %s: %.1f s, %llu samples", options.out.c_str(),
                            static_cast<double>(s.t_ns - t0) * 1e-9, static_cast<unsigned long long>(n));
    }
    st = source->read(s);
    // A silent moment on a live source is not the end of the recording.
    while (st == drivers::ReadStatus::timeout && !termination_requested()) st = source->read(s);
  }
  if (st == drivers::ReadStatus::error) {
    // What was recorded up to the error is kept (complete rows), and the error named.
    std::fprintf(stderr, "\nsource error: %s\n", source->last_error().c_str());
    code = 1;
  }
  if (tty) std::fprintf(stderr, "\n");
  if (!writer.close(error)) {
    std::fprintf(stderr, "cannot finish %s: %s; nothing written\n", options.out.c_str(), error.c_str());
    give_up();
    return 1;
  }
  config::unregister_scratch_file(writer.partial_path());
  std::printf("recorded %llu samples (%.3f s) of axis '%s' to %s%s%s%s\n", static_cast<unsigned long long>(n),
              static_cast<double>(s.t_ns - t0) * 1e-9, axis->name.c_str(), options.out.c_str(),
              cols.truth ? ", with truth" : "", cols.reference ? ", with reference" : "",
              termination_signal() == SIGINT    ? " (ended by SIGINT)"
              : termination_signal() == SIGTERM ? " (ended by SIGTERM)"
                                                : "");
  return code;
}

namespace {

/// What `evaluate` scores the estimate against.
enum class Basis { truth, ruler, none };
const char* basis_name(Basis b) { return b == Basis::truth ? "truth" : b == Basis::ruler ? "ruler" : "none"; }

/// `--ruler-offset`: what is subtracted from the ruler's reading before comparing.
struct RulerOffset {
  enum class Mode { automatic, none, fixed } mode = Mode::automatic;
  double m = 0.0;  ///< Mode::fixed
};

bool parse_ruler_offset(const std::string& text, RulerOffset& out) {
  if (text == "auto") {
    out.mode = RulerOffset::Mode::automatic;
    return true;
  }
  if (text == "none") {
    out.mode = RulerOffset::Mode::none;
    return true;
  }
  char* end = nullptr;
  const double m = std::strtod(text.c_str(), &end);
  if (text.empty() || end == nullptr || *end != '\0' || !std::isfinite(m)) return false;
  out.mode = RulerOffset::Mode::fixed;
  out.m = m;
  return true;
}

/// The estimate against a reference ruler, streaming except for one error and one
/// sigma per scored row (the offset must be known before the +-2 sigma coverage is).
/// The ruler's velocity comes from core::differentiate over a sliding window of
/// 2 * half_window + 1 consecutive, uniformly spaced readings; the window's centre
/// is compared with the estimate of the same row.
class RulerScore {
 public:
  RulerScore(double ts_s, int half_window)
      : ts_(ts_s), h_(half_window), n_(2 * half_window + 1), ring_(static_cast<std::size_t>(n_)),
        window_(static_cast<std::size_t>(n_)), cubic_(static_cast<std::size_t>(n_)) {
    // The cubic term of the motion over the window, orthogonal to the quadratic fit:
    // p3(k) = k^3 - alpha k with alpha = sum k^4 / sum k^2. A cubic c3 k^3 in the
    // readings shifts the fit's slope by alpha c3 per sample.
    double s2 = 0.0, s4 = 0.0;
    for (int k = -h_; k <= h_; ++k) {
      s2 += static_cast<double>(k) * k;
      s4 += static_cast<double>(k) * k * k * k;
    }
    alpha_ = s4 / s2;
    for (int k = -h_; k <= h_; ++k) {
      const double p3 = static_cast<double>(k) * k * k - alpha_ * k;
      cubic_[static_cast<std::size_t>(k + h_)] = p3;
      cubic_norm_ += p3 * p3;
    }
  }

  /// One row inside the evaluation window; `ref` null: the row has no ruler reading.
  void add(double t_s, const core::EncoderEstimate& est, const double* ref) {
    if (ref == nullptr) {
      ++without_reference_;
      have_last_ = false;
      run_ = 0;
      return;
    }
    if (have_last_) {
      const double step = std::abs(*ref - last_ref_);
      if (step > 1e-12 && (min_step_ == 0.0 || step < min_step_)) min_step_ = step;
      const double dt = t_s - last_t_;
      if (ts_ <= 0.0 && dt > 0.0) ts_ = dt;  // no sample_rate_hz in the log: the first interval
      if (dt < 0.5 * ts_ || dt > 1.5 * ts_) run_ = 0;  // a gap: the derivative starts again
    }
    have_last_ = true;
    last_ref_ = *ref;
    last_t_ = t_s;
    raw_error_m_.push_back(est.position_m - *ref);
    position_std_m_.push_back(static_cast<float>(est.position_std_m));
    position_std_sum_m_ += est.position_std_m;
    if (!(est.status & core::status::kValid)) ++not_valid_;

    ring_[head_] = {*ref, est.velocity_mps, est.velocity_std_mps};
    head_ = (head_ + 1) % ring_.size();
    run_ = std::min(run_ + 1, n_);
    if (run_ == n_) score_velocity();
  }

  /// Position statistics with the offset removed; call once, after the last add().
  void finish(const RulerOffset& offset) {
    double mean = 0.0;
    for (double e : raw_error_m_) mean += e;
    if (!raw_error_m_.empty()) mean /= static_cast<double>(raw_error_m_.size());
    offset_m_ = offset.mode == RulerOffset::Mode::automatic ? -mean
                : offset.mode == RulerOffset::Mode::fixed  ? offset.m
                                                           : 0.0;
    for (std::size_t i = 0; i < raw_error_m_.size(); ++i) {
      const double e = raw_error_m_[i] + offset_m_;  // estimate - (ruler - offset)
      position_.add(e);
      if (std::abs(e) <= 2.0 * position_std_m_[i]) ++position_within_;
    }
  }

  const core::ErrorAccumulator& position() const { return position_; }
  const core::ErrorAccumulator& velocity() const { return velocity_; }
  double position_coverage() const { return fraction(position_within_, position_.count()); }
  double velocity_coverage() const { return fraction(velocity_within_, velocity_.count()); }
  std::uint64_t not_valid() const { return not_valid_; }
  std::uint64_t without_reference() const { return without_reference_; }
  double offset_m() const { return offset_m_; }
  double mean_position_std_m() const {
    return position_std_m_.empty() ? 0.0 : position_std_sum_m_ / static_cast<double>(position_std_m_.size());
  }
  /// Smallest non-zero step between consecutive readings [m]; 0: none seen.
  double smallest_step_m() const { return min_step_; }
  double ts_s() const { return ts_; }
  int half_window() const { return h_; }
  /// The ruler's noise about the local quadratic fit, from the fit's residual at the
  /// window's centre (whose variance is (1 - w00) sigma^2 for white noise) [m].
  double noise_m() const { return residual_.rms() / std::sqrt(1.0 - centre_weight()); }
  /// The derivative's noise for a ruler noise `sigma_m`: the quadratic Savitzky-Golay
  /// slope is sum k x_k / (Ts sum k^2) [m/s].
  double velocity_noise_mps(double sigma_m) const {
    const double s2 = static_cast<double>(h_) * (h_ + 1) * (2 * h_ + 1) / 3.0;
    return ts_ > 0.0 ? sigma_m / (ts_ * std::sqrt(s2)) : 0.0;
  }
  /// RMS of the derivative's own error from the motion's curvature (the cubic term
  /// a quadratic fit misses), from the cubic coefficient of each window with the
  /// share of the ruler's noise in it taken out [m/s].
  double velocity_curvature_mps() const {
    if (ts_ <= 0.0 || curvature_.count() == 0) return 0.0;
    const double noise = alpha_ / ts_ * noise_m() / std::sqrt(cubic_norm_);
    const double ms = curvature_.rms() * curvature_.rms() - noise * noise;
    return ms > 0.0 ? std::sqrt(ms) : 0.0;
  }

 private:
  struct Slot {
    double ref_m, velocity_mps, velocity_std_mps;
  };
  static double fraction(std::uint64_t a, std::uint64_t n) { return n ? static_cast<double>(a) / n : 0.0; }
  /// Weight of the centre sample in the quadratic Savitzky-Golay smoother.
  double centre_weight() const {
    const double h = h_;
    return 3.0 * (3.0 * h * h + 3.0 * h - 1.0) / ((2.0 * h - 1.0) * (2.0 * h + 1.0) * (2.0 * h + 3.0));
  }
  void score_velocity() {
    for (int k = 0; k < n_; ++k) window_[static_cast<std::size_t>(k)] = ring_[(head_ + static_cast<std::size_t>(k)) % ring_.size()].ref_m;
    core::differentiate(window_, ts_, h_, v_, a_, valid_);
    const std::size_t c = static_cast<std::size_t>(h_);
    const Slot& centre = ring_[(head_ + c) % ring_.size()];
    const double e = centre.velocity_mps - v_[c];
    velocity_.add(e);
    if (std::abs(e) <= 2.0 * centre.velocity_std_mps) ++velocity_within_;
    // Residual of the quadratic fit at the centre: x_0 - (mean(d) - c2 M), d_k = x_k - x_0.
    double mean_d = 0.0;
    for (double x : window_) mean_d += x - window_[c];
    mean_d /= n_;
    const double mean_k2 = static_cast<double>(h_) * (h_ + 1) / 3.0;
    residual_.add(0.5 * a_[c] * ts_ * ts_ * mean_k2 - mean_d);
    double c3 = 0.0;
    for (std::size_t k = 0; k < window_.size(); ++k) c3 += cubic_[k] * (window_[k] - window_[c]);
    curvature_.add(alpha_ * c3 / cubic_norm_ / ts_);
  }

  double ts_;
  int h_, n_;
  std::vector<Slot> ring_;
  std::size_t head_ = 0;
  int run_ = 0;  // consecutive uniformly spaced readings in the ring
  std::vector<double> window_, v_, a_, cubic_;
  double alpha_ = 0.0, cubic_norm_ = 0.0;
  std::vector<char> valid_;
  bool have_last_ = false;
  double last_ref_ = 0.0, last_t_ = 0.0, min_step_ = 0.0;
  std::vector<double> raw_error_m_;     // estimate - ruler, per row with a reading
  std::vector<float> position_std_m_;
  double position_std_sum_m_ = 0.0;
  core::ErrorAccumulator position_, velocity_, residual_, curvature_;
  std::uint64_t position_within_ = 0, velocity_within_ = 0, not_valid_ = 0, without_reference_ = 0;
  double offset_m_ = 0.0;
};

/// Without truth or ruler: is the estimator consistent with itself and its sensors?
class ConsistencyCheck {
 public:
  explicit ConsistencyCheck(int hall_count) : hall_count_(hall_count) {}

  void add(const core::EncoderEstimate& est) {
    ++n_;
    if (est.hall_sensors_used > 0) {  // a Hall fix met the filter (not while acquiring)
      const double nu = est.hall_innovation_sigma;
      innovation_.add(nu);
      if (std::abs(nu) > 3.0) ++beyond_3_;
      if (std::abs(nu) > 6.0) ++beyond_6_;
    }
    position_std_m_.push_back(static_cast<float>(est.position_std_m));
    velocity_std_mps_.push_back(static_cast<float>(est.velocity_std_mps));
    for (int b = 0; b < 32; ++b)
      if (est.status >> b & 1u) ++status_set_[b];
    for (int i = 0; i < hall_count_; ++i) {
      if (est.hall_faulty_mask >> i & 1u) ++hall_faulty_[i];
      if (est.hall_outlier_mask >> i & 1u) ++hall_outlier_[i];
    }
    if (n_ == 1) accel_bias_start_ = est.accel_bias_mps2;
    accel_bias_end_ = est.accel_bias_mps2;
  }

  std::uint64_t count() const { return n_; }
  const core::ErrorAccumulator& innovation() const { return innovation_; }
  double beyond_3() const { return fraction(beyond_3_, innovation_.count()); }
  double beyond_6() const { return fraction(beyond_6_, innovation_.count()); }
  double status_fraction(int bit) const { return fraction(status_set_[bit], n_); }
  double hall_faulty(int i) const { return fraction(hall_faulty_[i], n_); }
  double hall_outlier(int i) const { return fraction(hall_outlier_[i], n_); }
  int hall_count() const { return hall_count_; }
  double accel_bias_start() const { return accel_bias_start_; }
  double accel_bias_end() const { return accel_bias_end_; }

  /// Mean, median, 95th and 99th percentile and largest of the published sigmas, scaled.
  struct Spread {
    double mean, p50, p95, p99, max;
  };
  Spread position_std(double scale) { return spread(position_std_m_, scale); }
  Spread velocity_std(double scale) { return spread(velocity_std_mps_, scale); }

 private:
  static double fraction(std::uint64_t a, std::uint64_t n) { return n ? static_cast<double>(a) / n : 0.0; }
  static Spread spread(std::vector<float>& v, double scale) {
    if (v.empty()) return {0, 0, 0, 0, 0};
    double sum = 0.0;
    for (float x : v) sum += x;
    std::sort(v.begin(), v.end());
    auto at = [&](double q) { return scale * v[static_cast<std::size_t>(q * static_cast<double>(v.size() - 1) + 0.5)]; };
    return {scale * sum / static_cast<double>(v.size()), at(0.5), at(0.95), at(0.99), scale * v.back()};
  }

  int hall_count_;
  std::uint64_t n_ = 0;
  core::ErrorAccumulator innovation_;
  std::uint64_t beyond_3_ = 0, beyond_6_ = 0;
  std::vector<float> position_std_m_, velocity_std_mps_;
  std::uint64_t status_set_[32] = {};
  std::uint64_t hall_faulty_[core::kMaxHalls] = {};
  std::uint64_t hall_outlier_[core::kMaxHalls] = {};
  double accel_bias_start_ = 0.0, accel_bias_end_ = 0.0;
};

/// The status bits a report names: the flags, then each Hall sensor's fault bit.
struct StatusBit {
  int bit;
  std::string name;
};
std::vector<StatusBit> status_bits(int hall_count) {
  std::vector<StatusBit> bits;
  for (int b = 0; b < 8; ++b) bits.push_back({b, core::status_to_string(1u << b)});
  for (int i = 0; i < hall_count; ++i)
    bits.push_back({core::status::kHallFaultShift + i, core::status_to_string(core::status::hall_fault(i))});
  return bits;
}

/// "position_um": {...}, "velocity_mmps": {...}, "coverage_2sigma": {...} (the truth report's keys).
std::string errors_json(const core::ErrorAccumulator& p, double p_cov, const core::ErrorAccumulator& v, double v_cov) {
  return fmt::sprintf("\"position_um\": {\"rms\": %.6f, \"bias\": %.6f, \"std\": %.6f, \"max\": %.6f}, "
                "\"velocity_mmps\": {\"rms\": %.6f, \"bias\": %.6f, \"std\": %.6f, \"max\": %.6f}, "
                "\"coverage_2sigma\": {\"position\": %.4f, \"velocity\": %.4f}",
                p.rms() * 1e6, p.bias() * 1e6, p.std_dev() * 1e6, p.max_abs() * 1e6, v.rms() * 1e3, v.bias() * 1e3,
                v.std_dev() * 1e3, v.max_abs() * 1e3, p_cov, v_cov);
}

void print_errors_text(const core::ErrorAccumulator& p, double p_cov, const core::ErrorAccumulator& v, double v_cov) {
  std::printf("  position error [um]:   rms %8.3f  bias %+8.3f  std %8.3f  max %8.3f   (+-2 sigma: %.1f %%)\n",
              p.rms() * 1e6, p.bias() * 1e6, p.std_dev() * 1e6, p.max_abs() * 1e6, 100 * p_cov);
  std::printf("  velocity error [mm/s]: rms %8.4f  bias %+8.4f  std %8.4f  max %8.4f   (+-2 sigma: %.1f %%)\n",
              v.rms() * 1e3, v.bias() * 1e3, v.std_dev() * 1e3, v.max_abs() * 1e3, 100 * v_cov);
}

std::string ruler_json(const RulerScore& r, const RulerOffset& offset, double resolution_m, bool estimated) {
  const char* mode = offset.mode == RulerOffset::Mode::automatic ? "auto"
                     : offset.mode == RulerOffset::Mode::fixed  ? "fixed"
                                                                : "none";
  return fmt::sprintf("\"ruler\": {\"resolution_um\": %.6f, \"resolution_estimated\": %s, \"offset_mode\": \"%s\", "
                "\"offset_m\": %.9f, \"rows_without_reference\": %llu, \"velocity_evaluated\": %llu, "
                "\"sg_half_window\": %d, \"sg_window_s\": %.6g, \"noise_um\": %.6f, "
                "\"velocity_noise_floor_mmps\": %.6f, \"velocity_resolution_floor_mmps\": %.6f, "
                "\"velocity_curvature_error_mmps\": %.6f}",
                resolution_m * 1e6, estimated ? "true" : "false", mode, r.offset_m(),
                static_cast<unsigned long long>(r.without_reference()),
                static_cast<unsigned long long>(r.velocity().count()), r.half_window(),
                (2 * r.half_window() + 1) * r.ts_s(), r.noise_m() * 1e6, r.velocity_noise_mps(r.noise_m()) * 1e3,
                r.velocity_noise_mps(resolution_m / std::sqrt(12.0)) * 1e3, r.velocity_curvature_mps() * 1e3);
  const double scatter_m = std::max(r.noise_m(), resolution_m / std::sqrt(12.0));
  if (scatter_m > 0.5 * r.mean_position_std_m())
    std::printf("  note: the ruler's own scatter (%.3f um) is comparable with the published position sigma (mean %.3f "
                "um): the position error and its +-2 sigma coverage include the ruler's error\n",
                scatter_m * 1e6, r.mean_position_std_m() * 1e6);
}

void print_ruler_text(const RulerScore& r, const RulerOffset& offset, double resolution_m, bool estimated) {
  if (resolution_m > 0.0)
    std::printf("  ruler resolution %.4g um (%s)\n", resolution_m * 1e6,
                estimated ? "estimated: the smallest step between consecutive distinct readings; the true step is "
                            "at most this"
                          : "--ruler-resolution-um");
  else
    std::printf("  ruler resolution unknown (the ruler never moved; give --ruler-resolution-um)\n");
  if (offset.mode == RulerOffset::Mode::automatic)
    std::printf("  ruler offset %.9f m removed (auto: the mean of ruler - estimate; the position bias is zero by "
                "construction)\n", r.offset_m());
  else if (offset.mode == RulerOffset::Mode::fixed)
    std::printf("  ruler offset %.9f m removed (--ruler-offset)\n", r.offset_m());
  else
    std::printf("  ruler offset: none removed (--ruler-offset none)\n");
  std::printf("  ruler velocity: quadratic Savitzky-Golay derivative over %d samples (%.3g ms), %llu samples scored\n",
              2 * r.half_window() + 1, (2 * r.half_window() + 1) * r.ts_s() * 1e3,
              static_cast<unsigned long long>(r.velocity().count()));
  std::printf("  ruler velocity noise floor [mm/s]: %.4f from the ruler's scatter about the fit (%.4f um), %.4f from "
              "its resolution alone\n",
              r.velocity_noise_mps(r.noise_m()) * 1e3, r.noise_m() * 1e6,
              r.velocity_noise_mps(resolution_m / std::sqrt(12.0)) * 1e3);
  std::printf("  ruler velocity curvature error [mm/s]: %.4f (motion the quadratic fit misses: a shorter window lowers "
              "it, a longer one the noise)\n  a velocity error near these floors is the ruler's, not the estimate's\n",
              r.velocity_curvature_mps() * 1e3);
  const double scatter_m = std::max(r.noise_m(), resolution_m / std::sqrt(12.0));
  if (scatter_m > 0.5 * r.mean_position_std_m())
    std::printf("  note: the ruler's own scatter (%.3f um) is comparable with the published position sigma (mean %.3f "
                "um): the position error and its +-2 sigma coverage include the ruler's error\n",
                scatter_m * 1e6, r.mean_position_std_m() * 1e6);
}

std::string consistency_json(ConsistencyCheck& c) {
  const auto& nu = c.innovation();
  const auto ps = c.position_std(1e6);
  const auto vs = c.velocity_std(1e3);
  std::string out = fmt::sprintf(
      "\"consistency\": {\"innovation\": {\"samples\": %llu, \"mean\": %.6f, \"rms\": %.6f, \"beyond_3\": %.6f, "
      "\"beyond_6\": %.6f}, "
      "\"position_std_um\": {\"mean\": %.6f, \"p50\": %.6f, \"p95\": %.6f, \"p99\": %.6f, \"max\": %.6f}, "
      "\"velocity_std_mmps\": {\"mean\": %.6f, \"p50\": %.6f, \"p95\": %.6f, \"p99\": %.6f, \"max\": %.6f}, "
      "\"valid_fraction\": %.6f, \"accel_bias_mps2\": {\"start\": %.6f, \"end\": %.6f}, \"status_fraction\": {",
      static_cast<unsigned long long>(nu.count()), nu.bias(), nu.rms(), c.beyond_3(), c.beyond_6(), ps.mean, ps.p50,
      ps.p95, ps.p99, ps.max, vs.mean, vs.p50, vs.p95, vs.p99, vs.max, c.status_fraction(0), c.accel_bias_start(),
      c.accel_bias_end());
  const auto bits = status_bits(c.hall_count());
  for (std::size_t i = 0; i < bits.size(); ++i)
    out += fmt::sprintf("%s\"%s\": %.6f", i ? ", " : "", bits[i].name.c_str(), c.status_fraction(bits[i].bit));
  out += "}, \"hall\": [";
  for (int i = 0; i < c.hall_count(); ++i)
    out += fmt::sprintf("%s{\"sensor\": %d, \"faulty\": %.6f, \"outlier\": %.6f}", i ? ", " : "", i, c.hall_faulty(i),
                  c.hall_outlier(i));
  return out + "]}";
}

void print_consistency_text(ConsistencyCheck& c) {
  std::printf("  no truth and no reference ruler in the log: accuracy cannot be scored, only the estimator's "
              "consistency with itself and its sensors\n");
  const auto& nu = c.innovation();
  std::printf("  normalised Hall innovation: mean %+.3f  rms %.3f (about 1 when consistent)  beyond 3: %.3f %%  "
              "beyond 6: %.3f %%  (%llu fixes)\n",
              nu.bias(), nu.rms(), 100 * c.beyond_3(), 100 * c.beyond_6(), static_cast<unsigned long long>(nu.count()));
  const auto ps = c.position_std(1e6);
  const auto vs = c.velocity_std(1e3);
  std::printf("  position sigma [um]:   mean %8.3f  p50 %8.3f  p95 %8.3f  p99 %8.3f  max %8.3f\n", ps.mean, ps.p50,
              ps.p95, ps.p99, ps.max);
  std::printf("  velocity sigma [mm/s]: mean %8.4f  p50 %8.4f  p95 %8.4f  p99 %8.4f  max %8.4f\n", vs.mean, vs.p50,
              vs.p95, vs.p99, vs.max);
  std::printf("  VALID: %.2f %% of samples\n", 100 * c.status_fraction(0));
  std::printf("  status flags set (%% of samples):");
  for (const auto& b : status_bits(c.hall_count())) std::printf(" %s %.2f", b.name.c_str(), 100 * c.status_fraction(b.bit));
  std::printf("\n  Hall sensors (%% of samples faulty / outlier):");
  for (int i = 0; i < c.hall_count(); ++i) std::printf(" H%d %.2f / %.2f", i, 100 * c.hall_faulty(i), 100 * c.hall_outlier(i));
  std::printf("\n  accelerometer bias estimate [m/s^2]: start %+.5f  end %+.5f\n", c.accel_bias_start(),
              c.accel_bias_end());
}

}  // namespace

namespace {

/// A CSV output written as PATH.partial and renamed to PATH once complete, so that
/// PATH is complete or absent. A PATH that exists and is not a regular file (a
/// FIFO, /dev/stdout) is written directly instead. Errors name the path and the reason.
class OutputFile {
 public:
  ~OutputFile() { discard(); }

  bool open(const std::string& path, std::string& error) {
    path_ = path;
    struct stat st {};
    direct_ = ::stat(path.c_str(), &st) == 0 && !S_ISREG(st.st_mode);
    if (direct_ && S_ISDIR(st.st_mode)) {
      error = "cannot write '" + path + "': it is a directory";
      return false;
    }
    target_ = direct_ ? path : path + ".partial";
    if (!direct_) config::register_scratch_file(target_);
    file_ = std::fopen(target_.c_str(), "w");
    if (file_ == nullptr) {
      error = "cannot write '" + target_ + "': " + std::strerror(errno);
      if (!direct_) config::unregister_scratch_file(target_);
      return false;
    }
    return true;
  }
  std::FILE* stream() const { return file_; }
  /// Flush, fsync, close, rename; false (nothing left under PATH.partial) on an error.
  bool commit(std::string& error) {
    int e = 0;
    if (std::fflush(file_) != 0 || std::ferror(file_)) e = errno ? errno : EIO;
    if (e == 0 && !direct_ && ::fsync(fileno(file_)) != 0) e = errno;
    const int c = std::fclose(file_);
    file_ = nullptr;
    if (e == 0 && c != 0) e = errno;
    if (e == 0 && !direct_ && std::rename(target_.c_str(), path_.c_str()) != 0) e = errno;
    if (e != 0) {
      error = "cannot write '" + path_ + "': " + std::strerror(e);
      discard();
      return false;
    }
    if (!direct_) config::unregister_scratch_file(target_);
    committed_ = true;
    return true;
  }
  /// Closes and removes the unfinished PATH.partial (nothing when committed).
  void discard() {
    if (file_ != nullptr) std::fclose(file_);
    file_ = nullptr;
    if (!direct_ && !committed_ && !target_.empty()) {
      ::unlink(target_.c_str());
      config::unregister_scratch_file(target_);
      target_.clear();
    }
  }

 private:
  std::string path_, target_;
  std::FILE* file_ = nullptr;
  bool direct_ = false;
  bool committed_ = false;
};

/// The most rows evaluate scores: a few numbers per row are kept (at most about 1 GB);
/// 67 million rows are 4.6 hours at 4 kHz.
constexpr std::uint64_t kMaxEvaluateRows = std::uint64_t{1} << 26;

std::string compact(double x) { return fmt::sprintf("%.6g", x); }

}  // namespace

int evaluate_command(const EvaluateOptions& options) {
  RulerOffset ruler_offset;
  if (!parse_ruler_offset(options.ruler_offset, ruler_offset)) {
    std::fprintf(stderr, "--ruler-offset: '%s' is neither auto, none nor a number of metres\n",
                 options.ruler_offset.c_str());
    return 2;
  }
  if (!(options.ruler_resolution_um >= 0.0) || !std::isfinite(options.ruler_resolution_um)) {
    std::fprintf(stderr, "--ruler-resolution-um: must be a number of micrometres >= 0 (0: estimate it from the readings)\n");
    return 2;
  }
  if (options.ruler_half_window < 1 || options.ruler_half_window > 10000) {
    std::fprintf(stderr, "--ruler-half-window: must be 1 to 10000 samples\n");
    return 2;
  }
  config::MachineConfig machine;
  const config::AxisConfig* found = load_axis(options.config, options.axis, machine);
  if (found == nullptr) return 2;
  config::AxisConfig axis = *found;
  if (!options.calibration.empty()) axis.calibration_file = options.calibration;
  if (options.home_m) {
    const double home = *options.home_m;
    if (!std::isfinite(home) || home < 0.0 || home > axis.motor.travel_m) {
      std::fprintf(stderr, "--home: %s m is outside the travel of axis '%s' (motor %s): [0, %s] m\n",
                   compact(home).c_str(), axis.name.c_str(), axis.motor.name.c_str(),
                   compact(axis.motor.travel_m).c_str());
      return 2;
    }
    axis.homing.position_m = home;
  }
  if (!options.estimates.empty()) {
    std::error_code ec;
    if (std::filesystem::equivalent(options.estimates, options.log, ec) && !ec) {
      std::fprintf(stderr, "--estimates %s is the log being read (--log %s): choose another file\n",
                   options.estimates.c_str(), options.log.c_str());
      return 2;
    }
  }
  core::Calibration cal;
  bool calibrated = false;
  std::string error;
  if (!load_axis_calibration(axis, cal, calibrated, error)) {
    std::fprintf(stderr, "%s", error.c_str());
    return 2;
  }
  replay::ReplaySource log(options.log, false);
  if (!log.ok()) {
    std::fprintf(stderr, "%s\n", log.last_error().c_str());
    return 2;
  }
  for (const auto& w : log.warnings()) std::fprintf(stderr, "warning: %s\n", w.c_str());
  if (log.meta().hall_count != axis.motor.hall.count) {
    std::fprintf(stderr, "%s: the log has %d Hall columns but motor '%s' has %d sensors\n", options.log.c_str(),
                 log.meta().hall_count, axis.motor.name.c_str(), axis.motor.hall.count);
    return 2;
  }
  const Basis basis = log.meta().has_truth ? Basis::truth : log.meta().has_reference ? Basis::ruler : Basis::none;
  double w0 = -1e300, w1 = 1e300;
  const bool windowed = log.meta().eval_window(w0, w1);

  OutputFile estimates;
  std::FILE* est_out = nullptr;
  if (!options.estimates.empty()) {
    if (!estimates.open(options.estimates, error)) {
      std::fprintf(stderr, "--estimates: %s\n", error.c_str());
      return 1;
    }
    est_out = estimates.stream();
    if (std::fprintf(est_out, "t_s,position_m,velocity_mps,position_std_m,velocity_std_mps,status\n") < 0) {
      std::fprintf(stderr, "--estimates: cannot write '%s': %s\n", options.estimates.c_str(), std::strerror(errno));
      return 1;
    }
  }

  core::AxisPipeline pipeline(pipeline_config(axis, cal, calibrated), cal.table);
  core::EstimateErrors e;
  RulerScore ruler(log.meta().sample_rate_hz > 0.0 ? 1.0 / log.meta().sample_rate_hz : 0.0,
                   options.ruler_half_window);
  ConsistencyCheck consistency(axis.motor.hall.count);
  core::RawSample s;
  std::uint64_t rows = 0;
  drivers::ReadStatus st;
  while ((st = log.read(s)) == drivers::ReadStatus::ok) {
    if (termination_requested()) {
      std::fprintf(stderr, "evaluate: interrupted by %s after %llu rows: nothing written\n",
                   termination_signal() == SIGTERM ? "SIGTERM" : "SIGINT", static_cast<unsigned long long>(rows));
      return interrupted_exit_code();  // the unfinished estimates are removed
    }
    if (++rows > kMaxEvaluateRows) {
      std::fprintf(stderr, "%s: more than %llu rows: too long to evaluate in one run (split the log)\n",
                   options.log.c_str(), static_cast<unsigned long long>(kMaxEvaluateRows));
      return 2;
    }
    const auto& est = pipeline.step(s);
    const double t = static_cast<double>(s.t_ns) * 1e-9;
    if (est_out != nullptr &&
        std::fprintf(est_out, "%.9f,%.9f,%.9f,%.3e,%.3e,%u\n", t, est.position_m, est.velocity_mps,
                     est.position_std_m, est.velocity_std_mps, est.status) < 0) {
      // errno is the write's own here (a full disk, a file size limit).
      std::fprintf(stderr, "--estimates: cannot write '%s': %s; nothing written\n", options.estimates.c_str(),
                   std::strerror(errno));
      return 1;  // the unfinished estimates are removed
    }
    if (t < w0 || t > w1) continue;
    if (basis == Basis::ruler) {
      double ref = 0.0;
      ruler.add(t, est, log.reference_position(ref) ? &ref : nullptr);
    } else if (basis == Basis::none) {
      consistency.add(est);
    } else if (const core::Truth* truth = log.truth()) {
      e.add(est.position_m - truth->position_m, est.position_std_m, est.velocity_mps - truth->velocity_mps,
            est.velocity_std_mps, (est.status & core::status::kValid) != 0);
    }
  }
  if (st == drivers::ReadStatus::error) {
    std::fprintf(stderr, "%s\n", log.last_error().c_str());
    return 2;  // the unfinished estimates are removed
  }
  if (est_out != nullptr && !estimates.commit(error)) {
    std::fprintf(stderr, "--estimates: %s\n", error.c_str());
    return 1;
  }
  if (basis == Basis::ruler) ruler.finish(ruler_offset);
  const std::uint64_t evaluated = basis == Basis::truth   ? e.position_m.count()
                                  : basis == Basis::ruler ? ruler.position().count()
                                                          : consistency.count();
  if (evaluated == 0) {
    std::fprintf(stderr, "no sample%s inside the evaluation window\n",
                 basis == Basis::truth ? " with truth" : basis == Basis::ruler ? " with a ruler reading" : "");
    return 1;
  }
  const double ruler_resolution_m =
      options.ruler_resolution_um > 0.0 ? options.ruler_resolution_um * 1e-6 : ruler.smallest_step_m();
  const bool resolution_estimated = !(options.ruler_resolution_um > 0.0);
  if (options.json) {
    std::string body;
    if (basis == Basis::truth)
      body = errors_json(e.position_m, e.position_coverage(), e.velocity_mps, e.velocity_coverage()) +
             fmt::sprintf(", \"not_valid\": %llu", static_cast<unsigned long long>(e.not_valid));
    else if (basis == Basis::ruler)
      body = errors_json(ruler.position(), ruler.position_coverage(), ruler.velocity(), ruler.velocity_coverage()) +
             fmt::sprintf(", \"not_valid\": %llu, ", static_cast<unsigned long long>(ruler.not_valid())) +
             ruler_json(ruler, ruler_offset, ruler_resolution_m, resolution_estimated);
    else
      body = consistency_json(consistency);
    std::printf("{\"log\": \"%s\", \"axis\": \"%s\", \"calibration\": \"%s\", \"basis\": \"%s\", \"samples\": %llu, "
                "\"evaluated\": %llu, \"window_s\": [%.9g, %.9g], %s}\n",
                options.log.c_str(), axis.name.c_str(), calibrated ? cal.info.id.c_str() : "", basis_name(basis),
                static_cast<unsigned long long>(rows), static_cast<unsigned long long>(evaluated), windowed ? w0 : 0.0,
                windowed ? w1 : static_cast<double>(s.t_ns) * 1e-9, body.c_str());
    return 0;
  }
  const char* against = basis == Basis::truth   ? "against the log's truth"
                        : basis == Basis::ruler ? "against a reference ruler (ref_position_m)"
                                                : "for consistency only";
  std::printf("evaluated %llu of %llu samples of %s (axis '%s', %s)%s %s\n", static_cast<unsigned long long>(evaluated),
              static_cast<unsigned long long>(rows), options.log.c_str(), axis.name.c_str(),
              calibrated ? ("calibration " + cal.info.id).c_str() : "nominal table",
              windowed ? " within eval_window_s" : "", against);
  std::uint64_t not_valid = 0;
  if (basis == Basis::truth) {
    print_errors_text(e.position_m, e.position_coverage(), e.velocity_mps, e.velocity_coverage());
    not_valid = e.not_valid;
  } else if (basis == Basis::ruler) {
    if (ruler.without_reference())
      std::printf("  %llu rows without a ruler reading were skipped\n",
                  static_cast<unsigned long long>(ruler.without_reference()));
    print_errors_text(ruler.position(), ruler.position_coverage(), ruler.velocity(), ruler.velocity_coverage());
    print_ruler_text(ruler, ruler_offset, ruler_resolution_m, resolution_estimated);
    not_valid = ruler.not_valid();
  } else {
    print_consistency_text(consistency);
  }
  if (not_valid) std::printf("  %llu samples were not VALID\n", static_cast<unsigned long long>(not_valid));
  return 0;
}

}  // namespace ve::app
