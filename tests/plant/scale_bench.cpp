// Scale benchmark: the CPU of `virtual-encoder run` with 1, 2, 4, 8 and 16 simulated axes
// at 4 kHz (all axes in one sample thread, `realtime.sample_loop: shared`; and again with
// one sample thread per axis, `per_axis`, without a subscriber), next to
//   - the pacing floor: threads that only wake at 4 kHz, paced as the product's sample
//     threads (ve_pace_floor), one thread and one per axis;
//   - a bare Fast DDS writer: one paced thread that writes N samples of
//     ve::dds::EncoderState per wake-up (ve_bare_writer), the same number of writes;
// each without a subscriber and with one (ve_bare_reader, the documented reader profile,
// in its own process), all in one run. CPU is utime + stime from /proc/PID/stat over a
// fixed window after a warm-up, in % of one core; the subscriber's samples received per
// second over the same window show whether the publisher kept its rate.
//
//   bench_scale [--axes 1,2,4,8,16] [--window S] [--warmup S] [--domain D] [--out FILE]
//
// Defaults: window 10 s, warm-up 3 s, domain 97 (a benchmark domain, docs/testing.md),
// out tests/bench/results/scale.md. The machines are config/machines/sim-8axis.yaml's
// first N axes (16: its eight twice, the copies with ids 9-16 and other noise seeds),
// written to a temporary directory with the motor path made absolute. Every process runs
// with FASTRTPS_DEFAULT_PROFILES_FILE=deploy/dds-profiles.xml (UDPv4 only).
// Prints the markdown table and writes it, with the host's load average before and after.
#include <fcntl.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <yaml-cpp/yaml.h>

namespace fs = std::filesystem;

namespace {

struct Child {
  pid_t pid = -1;
  std::string out;
};

Child spawn(const std::vector<std::string>& args, const std::string& out, const std::string& err,
            const std::string& profiles) {
  Child c;
  c.out = out;
  const pid_t parent = getpid();
  const pid_t pid = fork();
  if (pid == 0) {
    setpgid(0, 0);
    prctl(PR_SET_PDEATHSIG, SIGKILL);
    if (getppid() != parent) _exit(127);
    const int o = open(out.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    const int e = open(err.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    const int in = open("/dev/null", O_RDONLY);
    dup2(in, 0);
    dup2(o, 1);
    dup2(e, 2);
    setenv("FASTRTPS_DEFAULT_PROFILES_FILE", profiles.c_str(), 1);
    std::vector<char*> argv;
    for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
    argv.push_back(nullptr);
    execv(argv[0], argv.data());
    _exit(127);
  }
  c.pid = pid;
  return c;
}

void stop(Child& c) {
  if (c.pid <= 0) return;
  kill(-c.pid, SIGINT);
  for (int i = 0; i < 100; ++i) {
    int status = 0;
    if (waitpid(c.pid, &status, WNOHANG) == c.pid) {
      kill(-c.pid, SIGKILL);
      c.pid = -1;
      return;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  kill(-c.pid, SIGKILL);
  waitpid(c.pid, nullptr, 0);
  c.pid = -1;
}

/// utime + stime of a process (all its threads) in seconds; -1 when gone.
double cpu_seconds(pid_t pid) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/stat");
  std::string s;
  if (!std::getline(in, s)) return -1;
  const auto close = s.rfind(')');
  if (close == std::string::npos) return -1;
  std::istringstream rest(s.substr(close + 2));
  std::string field;
  unsigned long long utime = 0, stime = 0;
  for (int i = 3; i <= 15 && rest >> field; ++i) {
    if (i == 14) utime = std::stoull(field);
    if (i == 15) stime = std::stoull(field);
  }
  return static_cast<double>(utime + stime) / static_cast<double>(sysconf(_SC_CLK_TCK));
}

/// The last "received=N" a bare reader printed, 0 if none yet.
unsigned long long received(const std::string& out) {
  std::ifstream in(out);
  std::string line;
  unsigned long long n = 0;
  while (std::getline(in, line)) {
    const auto p = line.find("received=");
    if (line.rfind("ALIVE", 0) == 0 && p != std::string::npos) n = std::stoull(line.substr(p + 9));
  }
  return n;
}

bool wait_for_line(const std::string& file, const std::string& text, double seconds) {
  const auto until = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
  while (std::chrono::steady_clock::now() < until) {
    std::ifstream in(file);
    std::string s((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    if (s.find(text) != std::string::npos) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  return false;
}

std::string loadavg() {
  std::ifstream in("/proc/loadavg");
  double a = 0, b = 0, c = 0;
  in >> a >> b >> c;
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.2f %.2f %.2f", a, b, c);
  return buf;
}

/// The first n axes of sim-8axis.yaml (n up to 16: the eight again with ids + 8).
/// `sample_loop`: realtime.sample_loop of the machine ("" leaves the default, shared).
std::string write_machine(const fs::path& src_machine, int n, const fs::path& dir, const std::string& sample_loop = "") {
  YAML::Node m = YAML::LoadFile(src_machine.string());
  YAML::Node axes = m["axes"];
  YAML::Node out_axes(YAML::NodeType::Sequence);
  const int have = static_cast<int>(axes.size());
  for (int i = 0; i < n; ++i) {
    YAML::Node a = YAML::Clone(axes[i % have]);
    const int copy = i / have;
    if (copy > 0) {
      a["name"] = a["name"].as<std::string>() + std::to_string(copy + 1);
      a["id"] = a["id"].as<int>() + have * copy;
      a["driver"]["noise_seed"] = a["driver"]["noise_seed"].as<int>() + have * copy;
    }
    a["motor"] = fs::weakly_canonical(src_machine.parent_path() / a["motor"].as<std::string>()).string();
    out_axes.push_back(a);
  }
  m["axes"] = out_axes;
  m["machine"] = "scale-" + std::to_string(n);
  if (!sample_loop.empty()) m["realtime"]["sample_loop"] = sample_loop;
  const fs::path file = dir / ("scale-" + std::to_string(n) + (sample_loop.empty() ? "" : "-" + sample_loop) + ".yaml");
  std::ofstream(file) << m << "\n";
  return file.string();
}

struct Measure {
  double cpu_pct = -1;      // publisher, % of one core
  double sub_cpu_pct = -1;  // subscriber, % of one core
  double rx_per_s = -1;     // samples received per second by the subscriber
  double pub_per_s = -1;    // samples the publisher says it published, per second of its life
};

/// The samples a publisher says it published: `run`'s "published N samples" (stderr) or
/// the bare writer's "END written=N" (stdout); -1 when neither is there.
double published(const std::string& out, const std::string& err) {
  for (const auto& [file, key] : {std::pair<std::string, std::string>{err, "published "},
                                  std::pair<std::string, std::string>{out, "END written="}}) {
    std::ifstream in(file);
    std::string line;
    while (std::getline(in, line)) {
      const auto p = line.find(key);
      if (p != std::string::npos && (key != "published " || line.find(" samples;") != std::string::npos))
        return std::atof(line.c_str() + p + key.size());
    }
  }
  return -1;
}

}  // namespace

int main(int argc, char** argv) {
  std::vector<int> axis_counts{1, 2, 4, 8, 16};
  double window = 10.0, warmup = 3.0;
  int domain = 97;
  const fs::path src = VE_BENCH_SOURCE_DIR;
  std::string out_file = (src / "tests/bench/results/scale.md").string();
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string k = argv[i], v = argv[i + 1];
    if (k == "--axes") {
      axis_counts.clear();
      std::stringstream in(v);
      std::string item;
      while (std::getline(in, item, ',')) axis_counts.push_back(std::atoi(item.c_str()));
    } else if (k == "--window") window = std::atof(v.c_str());
    else if (k == "--warmup") warmup = std::atof(v.c_str());
    else if (k == "--domain") domain = std::atoi(v.c_str());
    else if (k == "--out") out_file = v;
    else {
      std::fprintf(stderr, "usage: bench_scale [--axes 1,2,4,8,16] [--window S] [--warmup S] [--domain D] [--out FILE]\n");
      return 2;
    }
  }
  const double rate = 4000.0;
  const std::string profiles = (src / "deploy/dds-profiles.xml").string();
  char tmpl[] = "/tmp/ve-scale-XXXXXX";
  const fs::path dir = mkdtemp(tmpl);
  const std::string load_before = loadavg();
  const std::string d = std::to_string(domain);

  // One measurement: start the subscriber (if any), then the publisher; warm up; window.
  auto measure = [&](const std::vector<std::string>& pub_args, bool with_sub, const std::string& tag) {
    Measure m;
    Child sub;
    const std::string sub_out = (dir / (tag + ".sub.out")).string();
    if (with_sub) {
      sub = spawn({VE_BARE_READER, d, "100000"}, sub_out, (dir / (tag + ".sub.err")).string(), profiles);
      wait_for_line(sub_out, "READY", 10);
    }
    const std::string pub_out = (dir / (tag + ".out")).string(), pub_err = (dir / (tag + ".err")).string();
    const auto t_spawn = std::chrono::steady_clock::now();
    Child pub = spawn(pub_args, pub_out, pub_err, profiles);
    std::this_thread::sleep_for(std::chrono::duration<double>(warmup));
    const double p0 = cpu_seconds(pub.pid), s0 = with_sub ? cpu_seconds(sub.pid) : 0;
    const unsigned long long r0 = with_sub ? received(sub_out) : 0;
    const auto t0 = std::chrono::steady_clock::now();
    std::this_thread::sleep_for(std::chrono::duration<double>(window));
    const double p1 = cpu_seconds(pub.pid), s1 = with_sub ? cpu_seconds(sub.pid) : 0;
    const double dt = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    if (p0 >= 0 && p1 >= 0) m.cpu_pct = 100.0 * (p1 - p0) / dt;
    if (with_sub) {
      // ALIVE lines come every 250 ms: give the last one time to be written.
      std::this_thread::sleep_for(std::chrono::milliseconds(300));
      const unsigned long long r1 = received(sub_out);
      if (s0 >= 0 && s1 >= 0) m.sub_cpu_pct = 100.0 * (s1 - s0) / dt;
      m.rx_per_s = static_cast<double>(r1 - r0) / (dt + 0.3);
    }
    const auto t_stop = std::chrono::steady_clock::now();
    stop(pub);
    stop(sub);
    const double n_pub = published(pub_out, pub_err);
    if (n_pub >= 0) m.pub_per_s = n_pub / std::chrono::duration<double>(t_stop - t_spawn).count();
    if (with_sub) {
      std::ifstream in(dir / (tag + ".sub.err"));
      const std::string e((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
      if (e.find("maximum number of instances") != std::string::npos)
        std::fprintf(stderr, "  %-22s the subscriber's reader reached its maximum number of instances\n", tag.c_str());
    }
    std::fprintf(stderr, "  %-22s cpu %6.1f %% published %.0f/s%s\n", tag.c_str(), m.cpu_pct, m.pub_per_s,
                 with_sub ? (" | subscriber " + std::to_string(m.sub_cpu_pct).substr(0, 5) + " %, received " +
                             std::to_string(static_cast<long long>(m.rx_per_s)) + "/s")
                                .c_str()
                          : "");
    std::this_thread::sleep_for(std::chrono::milliseconds(500));
    return m;
  };

  const std::string seconds = std::to_string(static_cast<int>(warmup + window + 30));
  std::fprintf(stderr, "scale benchmark: axes");
  for (int n : axis_counts) std::fprintf(stderr, " %d", n);
  std::fprintf(stderr, ", %.0f s window after %.0f s warm-up, domain %d, load average %s\n", window, warmup, domain,
               load_before.c_str());
  const Measure floor1 = measure({VE_PACE_FLOOR, "--threads", "1"}, false, "floor-1");
  struct Row {
    int n;
    Measure run, run_sub, run_per_axis, bare, bare_sub, floor_n;
  };
  std::vector<Row> rows;
  for (int n : axis_counts) {
    Row r;
    r.n = n;
    const std::string machine = write_machine(src / "config/machines/sim-8axis.yaml", n, dir);
    const std::string ns = std::to_string(n);
    const std::vector<std::string> run = {VE_BINARY, "run", "--config", machine, "--domain", d, "--duration", seconds,
                                          "--status-period", "60"};
    const std::vector<std::string> bare = {VE_BARE_WRITER, d, ns};
    r.run = measure(run, false, "run-" + ns);
    r.run_sub = measure(run, true, "run-sub-" + ns);
    const std::string per_axis = write_machine(src / "config/machines/sim-8axis.yaml", n, dir, "per_axis");
    r.run_per_axis = measure({VE_BINARY, "run", "--config", per_axis, "--domain", d, "--duration", seconds,
                              "--status-period", "60"},
                             false, "run-per-axis-" + ns);
    r.bare = measure(bare, false, "bare-" + ns);
    r.bare_sub = measure(bare, true, "bare-sub-" + ns);
    r.floor_n = n == 1 ? floor1 : measure({VE_PACE_FLOOR, "--threads", ns}, false, "floor-" + ns);
    rows.push_back(r);
  }
  const std::string load_after = loadavg();

  std::ostringstream md;
  char when[64];
  const std::time_t now = std::time(nullptr);
  std::strftime(when, sizeof when, "%Y-%m-%d %H:%M UTC", std::gmtime(&now));
  md << "# Scale: CPU of `run` against the number of axes\n\n"
     << "`build/tests/bench_scale` (tests/plant/scale_bench.cpp), " << when << ", " << std::thread::hardware_concurrency()
     << " CPUs, load average (1/5/15 min) " << load_before << " before, " << load_after << " after. "
     << "Every axis at " << static_cast<int>(rate) << " Hz; CPU is utime + stime of the publishing process over "
     << window << " s after " << warmup << " s of warm-up, in % of one core.\n\n"
     << "* `run`: `virtual-encoder run` on the first N axes of `config/machines/sim-8axis.yaml` (16: its eight twice),"
        " one state writer per axis; all axes in one sample thread (`realtime.sample_loop: shared`, the"
        " default: one wake-up per tick for every axis).\n"
     << "* `run`, thread per axis: the same with `realtime.sample_loop: per_axis`, one sample thread per axis"
        " (the design before the shared loop), measured in the same run.\n"
     << "* `run` / bare, `run` / floor: `run`'s CPU over the bare writer's and over the one-thread floor's, both"
        " without a subscriber (the issue's targets: <= 1.5 and <= 3 at 8 axes).\n"
     << "* bare writer: `ve_bare_writer`, one thread paced like the product's that writes N samples of"
        " `ve::dds::EncoderState` per wake-up through one writer (profile `ve_state_writer`), nothing else.\n"
     << "* floor: `ve_pace_floor`, threads that only wake at 4 kHz, paced like the product's; one thread, and one"
        " per axis.\n"
     << "* subscriber: `ve_bare_reader` (profile `ve_state_reader`) in its own process; its CPU and the samples"
        " it received per second (N x 4000 when nothing is lost). That profile sets no resource limits, so its"
        " reader keeps Fast DDS 2.9's default of at most 10 instances: with 16 axes it takes the samples of 10"
        " (at most 40,000/s); the publisher still sends all 16 (docs/scale.md).\n"
     << "* us/sample: the publisher's CPU divided by the samples it should publish (N x 4000 per second).\n"
     << "* published/s: the samples the publisher says it published (`run`'s last log line, the bare writer's"
        " END line), divided by its whole life from the exec (start-up included, so a little below N x 4000"
        " when it kept its rate), without / with the subscriber.\n\n"
     << "| axes | `run` | `run` + sub | `run`, thread per axis | bare writer | bare writer + sub | floor, 1 thread |"
        " floor, N threads | `run` / bare | `run` / floor | `run` us/sample | bare us/sample | published/s `run` |"
        " published/s bare | received/s `run` / bare | subscriber CPU `run` / bare |\n"
     << "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n";
  auto pct = [](double v) {
    char b[32];
    std::snprintf(b, sizeof b, "%.1f %%", v);
    return std::string(b);
  };
  for (const auto& r : rows) {
    char b[800];
    const double per = r.n * rate;
    std::snprintf(b, sizeof b,
                  "| %d | %s | %s | %s | %s | %s | %s | %s | %.2f | %.2f | %.1f | %.1f | %.0f / %.0f | %.0f / %.0f |"
                  " %.0f / %.0f | %s / %s |\n",
                  r.n, pct(r.run.cpu_pct).c_str(), pct(r.run_sub.cpu_pct).c_str(), pct(r.run_per_axis.cpu_pct).c_str(),
                  pct(r.bare.cpu_pct).c_str(), pct(r.bare_sub.cpu_pct).c_str(), pct(floor1.cpu_pct).c_str(),
                  pct(r.floor_n.cpu_pct).c_str(), r.run.cpu_pct / r.bare.cpu_pct, r.run.cpu_pct / floor1.cpu_pct,
                  r.run.cpu_pct * 1e4 / per, r.bare.cpu_pct * 1e4 / per, r.run.pub_per_s, r.run_sub.pub_per_s,
                  r.bare.pub_per_s, r.bare_sub.pub_per_s, r.run_sub.rx_per_s, r.bare_sub.rx_per_s,
                  pct(r.run_sub.sub_cpu_pct).c_str(), pct(r.bare_sub.sub_cpu_pct).c_str());
    md << b;
  }
  std::printf("%s", md.str().c_str());
  std::ofstream(out_file) << md.str();
  std::fprintf(stderr, "written to %s\n", out_file.c_str());
  fs::remove_all(dir);
  return 0;
}
