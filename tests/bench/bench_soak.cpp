// Soak benchmark (issue 7): `virtual-encoder run` on a 3-axis machine at 4 kHz per
// axis for a bounded time, with a subscriber in this process.
//
// Every interval it records, per interval and in total:
//  * the publisher's memory (VmRSS from /proc/PID/status) and CPU time
//    (utime + stime from /proc/PID/stat);
//  * per axis: samples received, sequence gaps (samples missing by their
//    sequence numbers) and requested-deadline misses (10 ms requested, twice the
//    5 ms offered, as `monitor` does);
//  * latency: this process' CLOCK_REALTIME when the sample is handed to it minus
//    the sample's source_time_ns (host CLOCK_REALTIME when the driver handed the
//    sample over), i.e. estimator + DDS write + transport + take; one host, one
//    clock. Percentiles from a 1 us histogram;
//  * where lost samples were lost: the kernel's drop counter of this process' UDP
//    sockets (/proc/net/udp: datagrams dropped because the socket's receive buffer
//    was full) and the largest receive queue seen (sampled every 50 ms), against the
//    publisher's own counters from ve/diagnostics (write failures, samples skipped
//    by the source). A gap with neither is lost in Fast DDS (e.g. a shared-memory
//    port queue) or in the reader's history.
// Then it crashes the publisher (SIGKILL) a few times and starts it again after
// 200 ms (the unit's RestartSec), measuring exec -> first sample received from the
// new process, and -> a sample from every axis.
//
// Prints a Markdown table over time and a summary, and writes them to
// tests/bench/results/soak.md. Not a ctest test; no pass/fail on timing.
//
//   bench_soak [--minutes M] [--interval-s S] [--warmup-s S] [--restarts N]
//              [--machine FILE] [--domain D] [--profiles FILE] [--out FILE | --no-write]
// --profiles: Fast DDS XML profiles for both processes (FASTRTPS_DEFAULT_PROFILES_FILE),
// e.g. deploy/dds-profiles.xml; without it both use the product's built-in QoS.
// CI-sized: the default 2 minutes. Long soak: --minutes 240 --interval-s 300.
#include <dirent.h>
#include <signal.h>
#include <spawn.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cinttypes>
#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fcntl.h>
#include <fstream>
#include <map>
#include <memory>
#include <mutex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <spdlog/spdlog.h>

#include "VirtualEncoder.h"
#include "app/dds_io.hpp"

#ifndef VE_BINARY
#define VE_BINARY "virtual-encoder"
#endif
#ifndef VE_BENCH_SOURCE_DIR
#define VE_BENCH_SOURCE_DIR "."
#endif

extern "C" char** environ;

namespace {

constexpr double kRequestedDeadlineMs = 10.0;  // what `monitor` requests: twice the machine's 5 ms

std::int64_t now_ns(clockid_t c) {
  timespec ts{};
  clock_gettime(c, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1000000000 + ts.tv_nsec;
}
std::int64_t rt_ns() { return now_ns(CLOCK_REALTIME); }
std::int64_t mono_ns() { return now_ns(CLOCK_MONOTONIC); }

std::string fmt(const char* f, ...) __attribute__((format(printf, 1, 2)));
std::string fmt(const char* f, ...) {
  char b[2048];
  va_list ap;
  va_start(ap, f);
  std::vsnprintf(b, sizeof b, f, ap);
  va_end(ap);
  return b;
}

// ------------------------------------------------------------------ latency histogram

/// 1 us bins up to 1 s; the rest in the last bin (the max is kept exactly).
class Histogram {
 public:
  Histogram() : bins_(kBins, 0) {}
  void add(std::int64_t ns) {
    const std::int64_t us = std::max<std::int64_t>(0, ns / 1000);
    ++bins_[static_cast<std::size_t>(std::min<std::int64_t>(us, kBins - 1))];
    ++n_;
    max_ns_ = std::max(max_ns_, ns);
  }
  void reset() {
    std::fill(bins_.begin(), bins_.end(), 0);
    n_ = 0;
    max_ns_ = 0;
  }
  void swap(Histogram& o) {
    bins_.swap(o.bins_);
    std::swap(n_, o.n_);
    std::swap(max_ns_, o.max_ns_);
  }
  void merge(const Histogram& o) {
    for (std::size_t i = 0; i < bins_.size(); ++i) bins_[i] += o.bins_[i];
    n_ += o.n_;
    max_ns_ = std::max(max_ns_, o.max_ns_);
  }
  std::uint64_t n() const { return n_; }
  double max_us() const { return max_ns_ * 1e-3; }
  /// Nearest-rank percentile [us], to the bin (1 us).
  double pct_us(double p) const {
    if (n_ == 0) return 0.0;
    const auto rank = static_cast<std::uint64_t>(std::ceil(p * static_cast<double>(n_)));
    std::uint64_t c = 0;
    for (std::size_t i = 0; i < bins_.size(); ++i) {
      c += bins_[i];
      if (c >= std::max<std::uint64_t>(rank, 1)) return static_cast<double>(i);
    }
    return max_us();
  }

 private:
  static constexpr std::int64_t kBins = 1000000;
  std::vector<std::uint64_t> bins_;
  std::uint64_t n_ = 0;
  std::int64_t max_ns_ = 0;
};

// ------------------------------------------------------------------ subscriber state

struct AxisCount {
  bool started = false;
  std::uint64_t last_seq = 0;
  std::uint64_t received = 0, gaps = 0, out_of_order = 0;
};

/// Filled on the DDS listener thread, read by the main thread under the mutex.
struct Collector {
  std::mutex mutex;
  std::int64_t incarnation_rt_ns = 0;  ///< samples stamped before this are from a killed process
  std::map<std::uint32_t, AxisCount> interval, total;
  Histogram interval_latency, total_latency;
  std::uint64_t stale = 0;
  // Restart measurement: first sample of the current incarnation, per axis.
  std::map<std::uint32_t, std::int64_t> first_mono;
  // The publisher's own counters, from its last ve/diagnostics sample per axis.
  struct Published {
    std::uint64_t samples = 0, skipped = 0, write_failures = 0;
  };
  std::map<std::uint32_t, Published> published;

  void on_diagnostics(const ve::dds::Diagnostics& d) {
    std::lock_guard<std::mutex> lock(mutex);
    if (d.publish_time_ns() < incarnation_rt_ns) return;
    Published& p = published[d.axis_id()];
    p.samples = d.samples_total();
    p.skipped = d.samples_skipped_total();
    p.write_failures = d.write_failures_total();
  }

  void on_sample(const ve::dds::EncoderState& s) {
    const std::int64_t arrival = rt_ns();
    const std::int64_t mono = mono_ns();
    std::lock_guard<std::mutex> lock(mutex);
    if (s.source_time_ns() < incarnation_rt_ns) {
      ++stale;
      return;
    }
    const std::uint32_t id = s.axis_id();
    first_mono.emplace(id, mono);
    AxisCount& t = total[id];
    AxisCount& i = interval[id];
    const std::uint64_t seq = s.sequence_number();
    if (t.started && seq > t.last_seq + 1) {
      t.gaps += seq - t.last_seq - 1;
      i.gaps += seq - t.last_seq - 1;
    } else if (t.started && seq <= t.last_seq) {
      ++t.out_of_order;
      ++i.out_of_order;
    }
    t.started = true;
    t.last_seq = std::max(t.last_seq, seq);
    ++t.received;
    ++i.received;
    interval_latency.add(arrival - s.source_time_ns());
  }
  /// A new publisher process: sequence numbers start again.
  void new_incarnation(std::int64_t exec_rt) {
    std::lock_guard<std::mutex> lock(mutex);
    incarnation_rt_ns = exec_rt;
    for (auto& [id, a] : total) a.started = false;
    first_mono.clear();
    published.clear();
  }
};

// ------------------------------------------------------------------ the publisher process

class Publisher {
 public:
  bool spawn(const std::vector<std::string>& args, const std::string& log) {
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_addopen(&fa, STDIN_FILENO, "/dev/null", O_RDONLY, 0);
    posix_spawn_file_actions_addopen(&fa, STDOUT_FILENO, log.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
    posix_spawn_file_actions_adddup2(&fa, STDOUT_FILENO, STDERR_FILENO);
    // Not this process' DDS sockets and shared-memory files: the publisher must not
    // hold them (and the socket counters below are then this process' alone).
    posix_spawn_file_actions_addclosefrom_np(&fa, STDERR_FILENO + 1);
    std::vector<char*> argv;
    for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
    argv.push_back(nullptr);
    const int rc = posix_spawn(&pid_, argv[0], &fa, nullptr, argv.data(), environ);
    posix_spawn_file_actions_destroy(&fa);
    if (rc != 0) pid_ = -1;
    return rc == 0;
  }
  pid_t pid() const { return pid_; }
  bool alive() const { return pid_ > 0 && waitpid(pid_, nullptr, WNOHANG) == 0; }
  void kill_now() {
    if (pid_ <= 0) return;
    kill(pid_, SIGKILL);
    waitpid(pid_, nullptr, 0);
    pid_ = -1;
  }
  /// SIGTERM and wait; returns the exit status (128 + signal when killed).
  int stop(double timeout_s) {
    if (pid_ <= 0) return -1;
    kill(pid_, SIGTERM);
    const auto until = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
    int st = 0;
    for (;;) {
      if (waitpid(pid_, &st, WNOHANG) == pid_) break;
      if (std::chrono::steady_clock::now() > until) {
        kill(pid_, SIGKILL);
        waitpid(pid_, &st, 0);
        break;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    pid_ = -1;
    return WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
  }
  ~Publisher() {
    if (pid_ > 0) stop(5.0);
  }

 private:
  pid_t pid_ = -1;
};

/// VmRSS [KiB] of a process; -1 when unreadable.
long rss_kib(pid_t pid) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/status");
  std::string line;
  while (std::getline(in, line))
    if (line.rfind("VmRSS:", 0) == 0) return std::strtol(line.c_str() + 6, nullptr, 10);
  return -1;
}

/// utime + stime [s] of a process; -1 when unreadable.
double cpu_s(pid_t pid) {
  std::ifstream f("/proc/" + std::to_string(pid) + "/stat");
  std::string all;
  if (!std::getline(f, all)) return -1;
  const auto rp = all.rfind(')');
  if (rp == std::string::npos) return -1;
  std::istringstream in(all.substr(rp + 2));
  std::string field;
  std::uint64_t utime = 0, stime = 0;
  for (int i = 3; i <= 15 && (in >> field); ++i) {
    if (i == 14) utime = std::strtoull(field.c_str(), nullptr, 10);
    if (i == 15) stime = std::strtoull(field.c_str(), nullptr, 10);
  }
  return static_cast<double>(utime + stime) / static_cast<double>(sysconf(_SC_CLK_TCK));
}

/// This process' UDP sockets (Fast DDS's receive sockets among them): their inodes,
/// for /proc/net/udp, and the largest receive buffer (SO_RCVBUF, as the kernel
/// accounts it: twice what was asked for).
struct UdpSockets {
  std::vector<unsigned long> inodes;
  int max_rcvbuf = 0;
  int min_rcvbuf = 0;
};

UdpSockets own_udp_sockets() {
  UdpSockets out;
  DIR* d = opendir("/proc/self/fd");
  if (d == nullptr) return out;
  while (dirent* e = readdir(d)) {
    const int fd = std::atoi(e->d_name);
    if (fd <= 2) continue;
    char link[256] = {};
    const std::string path = std::string("/proc/self/fd/") + e->d_name;
    const ssize_t n = readlink(path.c_str(), link, sizeof link - 1);
    if (n <= 0 || std::strncmp(link, "socket:[", 8) != 0) continue;
    int type = 0;
    socklen_t len = sizeof type;
    if (getsockopt(fd, SOL_SOCKET, SO_TYPE, &type, &len) != 0 || type != SOCK_DGRAM) continue;
    int rcvbuf = 0;
    len = sizeof rcvbuf;
    getsockopt(fd, SOL_SOCKET, SO_RCVBUF, &rcvbuf, &len);
    out.max_rcvbuf = std::max(out.max_rcvbuf, rcvbuf);
    out.min_rcvbuf = out.min_rcvbuf == 0 ? rcvbuf : std::min(out.min_rcvbuf, rcvbuf);
    out.inodes.push_back(std::strtoul(link + 8, nullptr, 10));
  }
  closedir(d);
  return out;
}

/// Sum of the kernel's drop counters and the largest receive queue [bytes] of the
/// given UDP sockets (/proc/net/udp and udp6).
struct UdpCounters {
  std::uint64_t drops = 0;
  std::uint64_t rx_queue_max = 0;
};

UdpCounters udp_counters(const std::vector<unsigned long>& inodes) {
  UdpCounters c;
  for (const char* file : {"/proc/net/udp", "/proc/net/udp6"}) {
    std::ifstream in(file);
    std::string line;
    std::getline(in, line);  // header
    while (std::getline(in, line)) {
      // sl local rem st tx_queue:rx_queue tr:tm->when retrnsmt uid timeout inode ref pointer drops
      std::istringstream f(line);
      std::string sl, local, rem, st, queues, tr, retr, uid, timeout, inode, ref, ptr, drops;
      if (!(f >> sl >> local >> rem >> st >> queues >> tr >> retr >> uid >> timeout >> inode >> ref >> ptr >> drops))
        continue;
      const unsigned long ino = std::strtoul(inode.c_str(), nullptr, 10);
      if (std::find(inodes.begin(), inodes.end(), ino) == inodes.end()) continue;
      c.drops += std::strtoull(drops.c_str(), nullptr, 10);
      const auto colon = queues.find(':');
      if (colon != std::string::npos)
        c.rx_queue_max = std::max<std::uint64_t>(c.rx_queue_max, std::strtoull(queues.c_str() + colon + 1, nullptr, 16));
    }
  }
  return c;
}

struct Row {
  double t_s = 0;
  long rss_kib = 0;
  double cpu_percent = 0;
  std::array<std::uint64_t, 3> received{};
  std::uint64_t gaps = 0, out_of_order = 0, deadline_missed = 0;
  std::uint64_t udp_drops = 0;         ///< datagrams the kernel dropped at this process' UDP sockets
  std::uint64_t rx_queue_max = 0;      ///< largest receive queue seen [bytes]
  std::uint64_t write_failures = 0;    ///< the publisher's failed state writes (ve/diagnostics)
  double p50 = 0, p99 = 0, p999 = 0, max = 0;
  double load1 = 0;  ///< the host's 1-minute load average
};

double load_average() {
  std::ifstream in("/proc/loadavg");
  double l = 0;
  in >> l;
  return l;
}

struct Options {
  double minutes = 2.0;
  double interval_s = 10.0;
  double warmup_s = 30.0;
  int restarts = 5;
  int domain = 78;
  std::string machine = std::string(VE_BENCH_SOURCE_DIR) + "/config/machines/sim-3axis.yaml";
  std::string out = std::string(VE_BENCH_SOURCE_DIR) + "/tests/bench/results/soak.md";
  std::string profiles;  ///< FASTRTPS_DEFAULT_PROFILES_FILE for both processes; empty: built-in QoS
  bool write = true;
};

std::string host_line() {
  char host[256] = "?";
  gethostname(host, sizeof host - 1);
  std::string cpu = "?";
  std::ifstream ci("/proc/cpuinfo");
  std::string l;
  while (std::getline(ci, l))
    if (l.rfind("model name", 0) == 0) {
      cpu = l.substr(l.find(':') + 2);
      break;
    }
  std::string kernel = "?";
  std::ifstream kv("/proc/sys/kernel/osrelease");
  std::getline(kv, kernel);
  return fmt("%s, %ld CPUs (%s), kernel %s", host, sysconf(_SC_NPROCESSORS_ONLN), cpu.c_str(), kernel.c_str());
}

double median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v.size() % 2 ? v[v.size() / 2] : 0.5 * (v[v.size() / 2 - 1] + v[v.size() / 2]);
}

int run(const Options& opt) {
  spdlog::set_level(spdlog::level::warn);
  const std::string log = "/tmp/bench_soak_run_" + std::to_string(getpid()) + ".log";
  std::remove(log.c_str());
  const double soak_s = opt.minutes * 60.0;
  // Both processes: this one's participant and the publisher (it inherits the environment).
  if (!opt.profiles.empty()) setenv("FASTRTPS_DEFAULT_PROFILES_FILE", opt.profiles.c_str(), 1);
  else unsetenv("FASTRTPS_DEFAULT_PROFILES_FILE");

  ve::app::DdsOptions o;
  o.domain = opt.domain;
  o.participant_name = "bench-soak-subscriber";
  std::string error;
  auto ctx = ve::app::DdsContext::create(o, error);
  if (!ctx) {
    std::fprintf(stderr, "%s\n", error.c_str());
    return 1;
  }
  Collector col;
  auto reader = std::make_unique<ve::app::StateReader>(
      *ctx, kRequestedDeadlineMs, [&col](const ve::dds::EncoderState& s) { col.on_sample(s); },
      [&col](const ve::dds::Diagnostics& d) { col.on_diagnostics(d); });
  if (!reader->ok()) {
    std::fprintf(stderr, "cannot create the readers\n");
    return 1;
  }
  auto deadline_missed = [&] {
    std::uint64_t n = 0;
    for (const auto& a : reader->snapshot()) n += a.deadline_missed;
    return n;
  };

  // The soak run: it waits for this subscriber, then publishes for the whole time.
  auto args = [&](double duration_s) {
    return std::vector<std::string>{VE_BINARY, "run", "--config", opt.machine, "--domain", std::to_string(opt.domain),
                                    "--duration", fmt("%.0f", duration_s), "--status-period", "10"};
  };
  Publisher pub;
  std::vector<std::string> first_args = args(soak_s + 5.0);
  first_args.push_back("--wait-for-subscriber");
  first_args.push_back("30");
  col.new_incarnation(rt_ns());
  if (!pub.spawn(first_args, log)) {
    std::fprintf(stderr, "cannot start %s\n", VE_BINARY);
    return 1;
  }
  // Wait for all three axes.
  const std::int64_t wait_until = mono_ns() + 40'000'000'000LL;
  for (;;) {
    {
      std::lock_guard<std::mutex> lock(col.mutex);
      if (col.first_mono.size() >= 3) break;
    }
    if (mono_ns() > wait_until || !pub.alive()) {
      std::fprintf(stderr, "no samples from all three axes; see %s\n", log.c_str());
      return 1;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  {
    std::lock_guard<std::mutex> lock(col.mutex);
    col.interval.clear();
    col.total.clear();
    col.interval_latency.reset();
  }
  // This process' UDP sockets (created with the participant; the shared-memory
  // transport opens none).
  const UdpSockets sockets = own_udp_sockets();
  const std::uint64_t drops_at_start = udp_counters(sockets.inodes).drops;
  auto write_failures = [&col] {
    std::lock_guard<std::mutex> lock(col.mutex);
    std::uint64_t n = 0;
    for (const auto& [id, p] : col.published) n += p.write_failures;
    return n;
  };
  const std::uint64_t write_failures_at_start = write_failures();
  std::printf("soak: %s, %.1f min, a row every %.0f s; publisher pid %d (log %s); QoS %s; subscriber: %zu UDP "
              "sockets, SO_RCVBUF %d..%d bytes\n",
              opt.machine.c_str(), opt.minutes, opt.interval_s, pub.pid(), log.c_str(),
              opt.profiles.empty() ? "built-in" : opt.profiles.c_str(), sockets.inodes.size(), sockets.min_rcvbuf,
              sockets.max_rcvbuf);
  const char* header =
      "| t [s] | RSS [MiB] | CPU [%] | samples x / y / z | gaps | UDP drops (subscriber) | rx queue max [KiB] | "
      "write failures | deadline misses | latency p50 / p99 / p99.9 / max [us] | host load |\n"
      "|---|---|---|---|---|---|---|---|---|---|---|\n";
  std::printf("%s", header);
  std::fflush(stdout);

  std::vector<Row> rows;
  const std::int64_t t0 = mono_ns();
  double last_cpu = cpu_s(pub.pid());
  std::int64_t last_t = t0;
  std::uint64_t last_missed = deadline_missed();
  const std::uint64_t missed_at_start = last_missed;
  std::uint64_t last_drops = drops_at_start, last_write_failures = write_failures_at_start;
  std::uint64_t rx_queue_max_total = 0;
  Histogram row_latency;  // the interval's histogram, swapped out of the collector
  for (int k = 1;; ++k) {
    const std::int64_t due = t0 + static_cast<std::int64_t>(std::min(k * opt.interval_s, soak_s) * 1e9);
    std::uint64_t rx_queue_max = 0;
    while (mono_ns() < due && pub.alive()) {
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
      rx_queue_max = std::max(rx_queue_max, udp_counters(sockets.inodes).rx_queue_max);
    }
    if (!pub.alive()) {
      std::fprintf(stderr, "the publisher ended early; see %s\n", log.c_str());
      return 1;
    }
    Row r;
    const std::int64_t now = mono_ns();
    r.t_s = (now - t0) * 1e-9;
    r.rss_kib = rss_kib(pub.pid());
    r.load1 = load_average();
    const double c = cpu_s(pub.pid());
    r.cpu_percent = 100.0 * (c - last_cpu) / ((now - last_t) * 1e-9);
    last_cpu = c;
    last_t = now;
    const std::uint64_t missed = deadline_missed();
    r.deadline_missed = missed - last_missed;
    last_missed = missed;
    const UdpCounters udp = udp_counters(sockets.inodes);
    r.udp_drops = udp.drops - last_drops;
    last_drops = udp.drops;
    r.rx_queue_max = std::max(rx_queue_max, udp.rx_queue_max);
    rx_queue_max_total = std::max(rx_queue_max_total, r.rx_queue_max);
    const std::uint64_t wf = write_failures();
    r.write_failures = wf - last_write_failures;
    last_write_failures = wf;
    row_latency.reset();
    {
      // Only swaps under the lock: the listener thread (which also drains the
      // socket) is never held up by the percentiles, the merge or the reset.
      std::lock_guard<std::mutex> lock(col.mutex);
      for (std::uint32_t id = 1; id <= 3; ++id) {
        const AxisCount& a = col.interval[id];
        r.received[id - 1] = a.received;
        r.gaps += a.gaps;
        r.out_of_order += a.out_of_order;
      }
      col.interval.clear();
      row_latency.swap(col.interval_latency);
    }
    r.p50 = row_latency.pct_us(0.50);
    r.p99 = row_latency.pct_us(0.99);
    r.p999 = row_latency.pct_us(0.999);
    r.max = row_latency.max_us();
    col.total_latency.merge(row_latency);  // the main thread's alone
    rows.push_back(r);
    std::printf("| %.0f | %.1f | %.1f | %" PRIu64 " / %" PRIu64 " / %" PRIu64 " | %" PRIu64 " | %" PRIu64
                " | %.0f | %" PRIu64 " | %" PRIu64 " | %.0f / %.0f / %.0f / %.0f | %.1f |\n",
                r.t_s, r.rss_kib / 1024.0, r.cpu_percent, r.received[0], r.received[1], r.received[2], r.gaps,
                r.udp_drops, r.rx_queue_max / 1024.0, r.write_failures, r.deadline_missed, r.p50, r.p99, r.p999,
                r.max, r.load1);
    std::fflush(stdout);
    if (r.t_s >= soak_s - 1e-3) break;
  }
  // Totals of the soak phase, before the restarts.
  Histogram total_latency;
  std::map<std::uint32_t, AxisCount> totals;
  std::uint64_t stale_before = 0;
  std::map<std::uint32_t, Collector::Published> published;
  total_latency.merge(col.total_latency);
  {
    std::lock_guard<std::mutex> lock(col.mutex);
    totals = col.total;
    stale_before = col.stale;
    published = col.published;
  }
  const std::uint64_t soak_drops = udp_counters(sockets.inodes).drops - drops_at_start;
  const std::uint64_t soak_missed = deadline_missed() - missed_at_start;

  // Restarts: SIGKILL, 200 ms (RestartSec), exec; time to the first sample, and to all axes.
  std::vector<double> to_first_ms, to_all_ms;
  for (int i = 0; i < opt.restarts; ++i) {
    pub.kill_now();
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
    const std::int64_t exec_mono = mono_ns();
    col.new_incarnation(rt_ns());
    if (!pub.spawn(args(60.0), log)) {
      std::fprintf(stderr, "cannot restart %s\n", VE_BINARY);
      return 1;
    }
    std::int64_t first = 0, all = 0;
    const std::int64_t until = exec_mono + 30'000'000'000LL;
    while (mono_ns() < until) {
      {
        std::lock_guard<std::mutex> lock(col.mutex);
        if (!col.first_mono.empty()) {
          first = col.first_mono.begin()->second;
          for (const auto& [id, t] : col.first_mono) first = std::min(first, t);
          if (col.first_mono.size() >= 3) {
            all = 0;
            for (const auto& [id, t] : col.first_mono) all = std::max(all, t);
            break;
          }
        }
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
    if (all == 0) {
      std::fprintf(stderr, "restart %d: not every axis came back within 30 s; see %s\n", i + 1, log.c_str());
      return 1;
    }
    to_first_ms.push_back((first - exec_mono) * 1e-6);
    to_all_ms.push_back((all - exec_mono) * 1e-6);
    std::printf("restart %d: exec -> first sample %.0f ms, -> every axis %.0f ms\n", i + 1, to_first_ms.back(),
                to_all_ms.back());
    std::fflush(stdout);
    std::this_thread::sleep_for(std::chrono::milliseconds(1000));
  }
  const int rc = pub.stop(10.0);
  if (rc != 0) std::fprintf(stderr, "the last publisher exited with %d\n", rc);
  reader.reset();
  ctx.reset();

  // ---- summary
  const Row* warm = nullptr;
  for (const auto& r : rows)
    if (r.t_s >= opt.warmup_s - 1e-3) {
      warm = &r;
      break;
    }
  if (warm == nullptr) warm = &rows.front();
  const Row& last = rows.back();
  // Least-squares slope of RSS over the rows after warm-up [KiB/min].
  double slope = 0;
  {
    double n = 0, sx = 0, sy = 0, sxx = 0, sxy = 0;
    for (const auto& r : rows)
      if (r.t_s >= warm->t_s) {
        n += 1;
        sx += r.t_s;
        sy += r.rss_kib;
        sxx += r.t_s * r.t_s;
        sxy += r.t_s * r.rss_kib;
      }
    if (n >= 2 && n * sxx - sx * sx > 0) slope = (n * sxy - sx * sy) / (n * sxx - sx * sx) * 60.0;
  }
  std::uint64_t received = 0, gaps = 0, ooo = 0;
  std::string per_axis;
  for (std::uint32_t id = 1; id <= 3; ++id) {
    const AxisCount& a = totals[id];
    received += a.received;
    gaps += a.gaps;
    ooo += a.out_of_order;
    per_axis += fmt("%s%u: %" PRIu64 " received, %" PRIu64 " gaps", per_axis.empty() ? "" : "; ", id, a.received, a.gaps);
  }
  double cpu_sum = 0;
  for (const auto& r : rows) cpu_sum += r.cpu_percent;

  std::string md;
  md += "# Soak benchmark\n\n";
  md += "`build/tests/bench_soak` (tests/bench/bench_soak.cpp): `virtual-encoder run` on `config/machines/sim-3axis.yaml` "
        "(3 simulated axes, 4 kHz each, no `realtime:` settings), a subscriber in the benchmark process (product "
        "StateReader, 10 ms requested deadline). Latency = subscriber's CLOCK_REALTIME at the hand-over minus the "
        "sample's `source_time_ns` (estimator + write + transport + take). Not a ctest test.\n\n";
  md += fmt("QoS: %s. The subscriber (participant `ve_participant` or its built-in equivalent) receives over UDPv4 "
            "(loopback): %zu UDP sockets, SO_RCVBUF %d..%d bytes (as the "
            "kernel accounts it, twice the size asked for). *UDP drops* = datagrams the kernel dropped at those sockets "
            "because a receive buffer was full (/proc/net/udp), *rx queue max* = the largest receive queue seen "
            "(sampled every 50 ms), *write failures* = the publisher's failed state writes (ve/diagnostics).\n\n",
            opt.profiles.empty() ? "the product's built-in QoS (no profiles file)"
                                 : ("XML profiles " + opt.profiles + " (FASTRTPS_DEFAULT_PROFILES_FILE, both processes)").c_str(),
            sockets.inodes.size(), sockets.min_rcvbuf, sockets.max_rcvbuf);
  md += "Where samples were lost before (issue 7): every sequence gap was a datagram the kernel dropped at the "
        "subscriber's UDP socket, whose receive buffer (Linux default 208 KiB, about 166 datagrams = 14 ms of the "
        "3-axis stream) overflowed while the subscriber's receive thread was descheduled; the publisher wrote every "
        "sample. The product's transports now ask for 4 MiB socket buffers and an 8192-message shared-memory port "
        "queue (deploy/dds-profiles.xml, docs/dds-interface.md).\n\n";
  md += fmt("Host: %s. Run: %.1f min, a row every %.0f s, warm-up %.0f s. The host load column is the 1-minute load "
            "average of the whole host (other work included): gaps, misses and the latency tail follow it.\n\n",
            host_line().c_str(), opt.minutes, opt.interval_s, opt.warmup_s);
  md += header;
  for (const auto& r : rows)
    md += fmt("| %.0f | %.1f | %.1f | %" PRIu64 " / %" PRIu64 " / %" PRIu64 " | %" PRIu64 " | %" PRIu64
              " | %.0f | %" PRIu64 " | %" PRIu64 " | %.0f / %.0f / %.0f / %.0f | %.1f |\n",
              r.t_s, r.rss_kib / 1024.0, r.cpu_percent, r.received[0], r.received[1], r.received[2], r.gaps,
              r.udp_drops, r.rx_queue_max / 1024.0, r.write_failures, r.deadline_missed, r.p50, r.p99, r.p999,
              r.max, r.load1);
  md += "\n## Summary\n\n";
  md += "| figure | value | target |\n|---|---|---|\n";
  md += fmt("| memory after warm-up (t = %.0f s → %.0f s) | %.1f → %.1f MiB (%+.0f KiB; slope %+.0f KiB/min) | no growth |\n",
            warm->t_s, last.t_s, warm->rss_kib / 1024.0, last.rss_kib / 1024.0,
            static_cast<double>(last.rss_kib - warm->rss_kib), slope);
  md += fmt("| samples received | %" PRIu64 " (%.0f /s per axis) | 4000 /s per axis |\n", received,
            received / 3.0 / (last.t_s > 0 ? last.t_s : 1));
  std::uint64_t warm_gaps = 0, warm_missed = 0;
  for (const auto& r : rows)
    if (r.t_s > warm->t_s) {
      warm_gaps += r.gaps;
      warm_missed += r.deadline_missed;
    }
  md += fmt("| sequence gaps, whole run | %" PRIu64 " (%s); out of order %" PRIu64 " | 0 |\n", gaps, per_axis.c_str(), ooo);
  md += fmt("| sequence gaps after warm-up | %" PRIu64 " | 0 |\n", warm_gaps);
  {
    std::uint64_t pub_samples = 0, pub_skipped = 0, pub_failures = 0;
    for (const auto& [id, p] : published) {
      pub_samples += p.samples;
      pub_skipped += p.skipped;
      pub_failures += p.write_failures;
    }
    md += fmt("| where: UDP datagrams dropped at the subscriber's sockets (receive buffer full), whole run | %" PRIu64
              " (largest receive queue seen %.0f KiB of %d) | 0 |\n",
              soak_drops, rx_queue_max_total / 1024.0, sockets.max_rcvbuf);
    md += fmt("| where: publisher's failed state writes / samples skipped by its sources (ve/diagnostics, since start) "
              "| %" PRIu64 " / %" PRIu64 " (of %" PRIu64 " published) | 0 |\n",
              pub_failures, pub_skipped, pub_samples);
  }
  md += fmt("| requested-deadline misses (10 ms), whole run / after warm-up | %" PRIu64 " / %" PRIu64 " | – |\n",
            soak_missed, warm_missed);
  md += fmt("| latency p50 / p99 / p99.9 / max | %.0f / %.0f / %.0f / %.0f us (%" PRIu64 " samples) | – |\n",
            total_latency.pct_us(0.5), total_latency.pct_us(0.99), total_latency.pct_us(0.999), total_latency.max_us(),
            total_latency.n());
  md += fmt("| publisher CPU (mean of the rows) | %.1f %% of one core | – |\n", rows.empty() ? 0.0 : cpu_sum / rows.size());
  if (!to_first_ms.empty()) {
    md += fmt("| restart: SIGKILL, 200 ms, exec → first sample (%zu restarts) | median %.0f ms, max %.0f ms | 1000 ms |\n",
              to_first_ms.size(), median(to_first_ms), *std::max_element(to_first_ms.begin(), to_first_ms.end()));
    md += fmt("| restart: exec → a sample of every axis | median %.0f ms, max %.0f ms | – |\n", median(to_all_ms),
              *std::max_element(to_all_ms.begin(), to_all_ms.end()));
    std::string each;
    for (std::size_t i = 0; i < to_first_ms.size(); ++i) each += fmt("%s%.0f", i ? ", " : "", to_first_ms[i]);
    md += "\nRestart times (exec → first sample) [ms]: " + each + ".\n";
  }
  (void)stale_before;
  std::printf("\n%s", md.substr(md.find("## Summary")).c_str());
  if (opt.write) {
    std::ofstream out(opt.out);
    out << md;
    std::printf("\nwritten to %s\n", opt.out.c_str());
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  Options opt;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto next = [&]() -> std::string {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "%s needs a value\n", a.c_str());
        std::exit(2);
      }
      return argv[++i];
    };
    if (a == "--minutes") opt.minutes = std::atof(next().c_str());
    else if (a == "--interval-s") opt.interval_s = std::atof(next().c_str());
    else if (a == "--warmup-s") opt.warmup_s = std::atof(next().c_str());
    else if (a == "--restarts") opt.restarts = std::atoi(next().c_str());
    else if (a == "--machine") opt.machine = next();
    else if (a == "--domain") opt.domain = std::atoi(next().c_str());
    else if (a == "--profiles") opt.profiles = next();
    else if (a == "--out") opt.out = next();
    else if (a == "--no-write") opt.write = false;
    else {
      std::printf("usage: %s [--minutes M (2)] [--interval-s S (10)] [--warmup-s S (30)] [--restarts N (5)]\n"
                  "          [--machine FILE] [--domain D (78)] [--profiles FILE] [--out FILE | --no-write]\n"
                  "long soak: --minutes 240 --interval-s 300\n",
                  argv[0]);
      return a == "--help" || a == "-h" ? 0 : 2;
    }
  }
  if (opt.minutes <= 0 || opt.interval_s <= 0) {
    std::fprintf(stderr, "--minutes and --interval-s must be > 0\n");
    return 2;
  }
  return run(opt);
}
