// Scale benchmark (--mode axes, the default): the CPU of `virtual-encoder run` with 1, 2, 4, 8 and 16 simulated axes
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
//   bench_scale [--mode axes|deadline] [--axes 1,2,4,8,16] [--window S] [--warmup S] [--domain D] [--out FILE]
//
// --mode deadline: the cost of the offered deadline instead, without a subscriber, for
// each number of axes: the bare writer with one keyed writer written in a fixed order,
// in alternating order, with one writer per axis and with no deadline; `run` with one
// state writer per sample thread (the default), one per axis (dds.state_writer:
// per_axis), with no deadline (VE_DDS_STATE_NO_DEADLINE=1) and without the state writers'
// pacing instance (VE_DDS_STATE_NO_PACER=1); next to the one-thread floor. Besides CPU it
// counts the voluntary context switches of the publisher's threads
// (/proc/PID/task/*/status), the pacing thread(s) apart from the others (Fast DDS's
// event thread is woken by every re-arm of a deadline timer).
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
#include <map>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <yaml-cpp/yaml.h>

#include "../integration/threads.hpp"

namespace fs = std::filesystem;

namespace {

struct Child {
  pid_t pid = -1;
  std::string out;
};

Child spawn(const std::vector<std::string>& args, const std::string& out, const std::string& err,
            const std::string& profiles, const std::vector<std::pair<std::string, std::string>>& env = {}) {
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
    for (const auto& [k, v] : env) setenv(k.c_str(), v.c_str(), 1);
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

/// Voluntary context switches of each thread of a process (tid -> count), and which
/// threads pace it: `run`'s sample threads (named ve-...), the bare writer's main thread.
struct TaskSwitches {
  std::map<int, unsigned long long> pacing, other;
};
TaskSwitches task_switches(pid_t pid) {
  TaskSwitches t;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator("/proc/" + std::to_string(pid) + "/task", ec)) {
    const int tid = std::atoi(e.path().filename().c_str());
    std::ifstream comm_in(e.path() / "comm");
    std::string comm;
    std::getline(comm_in, comm);
    const long long n = ve::test::voluntary_switches(e.path().string());
    if (n < 0) continue;
    // The bare writer's other threads (Fast DDS's) inherit its main thread's name.
    const bool pacing = comm.rfind("ve-", 0) == 0 || (tid == pid && comm == "ve_bare_writer");
    (pacing ? t.pacing : t.other)[tid] = n;
  }
  return t;
}
/// Switches per second between two readings, over the threads present in both.
double switches_per_s(const std::map<int, unsigned long long>& a, const std::map<int, unsigned long long>& b,
                      double dt) {
  unsigned long long n = 0;
  for (const auto& [tid, count] : b) {
    const auto it = a.find(tid);
    if (it != a.end()) n += count - it->second;
  }
  return static_cast<double>(n) / dt;
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
/// `state_writer`: dds.state_writer of the machine ("" leaves the default, per_group).
std::string write_machine(const fs::path& src_machine, int n, const fs::path& dir, const std::string& sample_loop = "",
                          const std::string& state_writer = "") {
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
  if (!state_writer.empty()) m["dds"]["state_writer"] = state_writer;
  const fs::path file = dir / ("scale-" + std::to_string(n) + (sample_loop.empty() ? "" : "-" + sample_loop) +
                               (state_writer.empty() ? "" : "-w" + state_writer) + ".yaml");
  std::ofstream(file) << m << "\n";
  return file.string();
}

struct Measure {
  double cpu_pct = -1;      // publisher, % of one core
  double sub_cpu_pct = -1;  // subscriber, % of one core
  double rx_per_s = -1;     // samples received per second by the subscriber
  double pub_per_s = -1;    // samples the publisher says it published, per second of its life
  double pacing_switches_per_s = -1;  // voluntary context switches of the pacing thread(s)
  double other_switches_per_s = -1;   // ... of every other thread of the publisher
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


/// --mode deadline: what the offered deadline costs and the ways to pay less, side by side
/// for each number of axes, with the floor: the bare writer with one keyed writer written
/// in one fixed order, in alternating order, one writer per axis, and no deadline; `run`
/// with one writer per sample thread (dds.state_writer: per_group, the default), one
/// writer per axis (per_axis), no deadline (VE_DDS_STATE_NO_DEADLINE=1), and one writer per
/// sample thread without its pacing instance (VE_DDS_STATE_NO_PACER=1). No subscriber.
template <class MeasureFn>
int deadline_table(MeasureFn& measure, const Measure& floor1, const std::vector<int>& axis_counts, const fs::path& src,
                   const fs::path& dir, const std::string& d, const std::string& seconds, double window,
                   double warmup, double rate, const std::string& load_before, const std::string& out_file) {
  struct Column {
    const char* head;
    std::string key;
  };
  const std::vector<Column> columns = {
      {"bare: one writer, fixed order", "bare-fixed"},     {"bare: one writer, alternating", "bare-alt"},
      {"bare: writer per axis", "bare-per-axis"},          {"bare: no deadline", "bare-none"},
      {"`run`: writer per sample thread", "run-group"},    {"`run`: writer per axis", "run-per-axis"},
      {"`run`: no deadline", "run-none"},          {"`run`: writer per sample thread, no pacing instance", "run-no-pacer"},
  };
  struct Row {
    int n;
    std::vector<Measure> m;
  };
  std::vector<Row> rows;
  for (int n : axis_counts) {
    Row r{n, {}};
    const std::string ns = std::to_string(n);
    const fs::path machines = src / "config/machines/sim-8axis.yaml";
    const std::string group = write_machine(machines, n, dir);
    const std::string per_axis = write_machine(machines, n, dir, "", "per_axis");
    auto run = [&](const std::string& machine) {
      return std::vector<std::string>{VE_BINARY, "run", "--config", machine, "--domain", d, "--duration", seconds,
                                      "--status-period", "60"};
    };
    for (const auto& c : columns) {
      const std::string tag = c.key + "-" + ns;
      if (c.key == "bare-fixed") r.m.push_back(measure({VE_BARE_WRITER, d, ns, "--order", "fixed"}, false, tag));
      if (c.key == "bare-alt") r.m.push_back(measure({VE_BARE_WRITER, d, ns, "--order", "alternate"}, false, tag));
      if (c.key == "bare-per-axis")
        r.m.push_back(measure({VE_BARE_WRITER, d, ns, "--writers", "per_axis"}, false, tag));
      if (c.key == "bare-none") r.m.push_back(measure({VE_BARE_WRITER, d, ns, "--deadline", "off"}, false, tag));
      if (c.key == "run-group") r.m.push_back(measure(run(group), false, tag));
      if (c.key == "run-per-axis") r.m.push_back(measure(run(per_axis), false, tag));
      if (c.key == "run-none") r.m.push_back(measure(run(group), false, tag, {{"VE_DDS_STATE_NO_DEADLINE", "1"}}));
      if (c.key == "run-no-pacer")
        r.m.push_back(measure(run(group), false, tag, {{"VE_DDS_STATE_NO_PACER", "1"}}));
    }
    rows.push_back(r);
  }
  const std::string load_after = loadavg();
  std::ostringstream md;
  char when[64];
  const std::time_t now = std::time(nullptr);
  std::strftime(when, sizeof when, "%Y-%m-%d %H:%M UTC", std::gmtime(&now));
  md << "`build/tests/bench_scale --mode deadline";
  if (axis_counts != std::vector<int>{1, 2, 4, 8, 16}) {
    md << " --axes ";
    for (std::size_t i = 0; i < axis_counts.size(); ++i) md << (i ? "," : "") << axis_counts[i];
  }
  md << "` (tests/plant/scale_bench.cpp), " << when << ", " << std::thread::hardware_concurrency()
     << " CPUs, load average (1/5/15 min) " << load_before << " before, " << load_after << " after. "
     << "Every axis at " << static_cast<int>(rate) << " Hz, no subscriber; CPU is utime + stime of the publishing"
     << " process over " << window << " s after " << warmup << " s of warm-up, in % of one core.\n\n";
  auto head = [&](const char* what) {
    md << "| axes | floor, 1 thread |";
    for (const auto& c : columns) md << " " << c.head << " |";
    md << " " << what << "\n|---:|---:|";
    for (std::size_t i = 0; i < columns.size(); ++i) md << "---:|";
    md << (what[0] ? "---:|---:|---:|\n" : "\n");
  };
  char b[128];
  head("`run` per thread / bare fixed | `run` per thread / bare, no deadline | `run` per thread / floor |");
  for (const auto& r : rows) {
    md << "| " << r.n << " | ";
    std::snprintf(b, sizeof b, "%.1f %%", floor1.cpu_pct);
    md << b << " |";
    for (const auto& m : r.m) {
      std::snprintf(b, sizeof b, " %.1f %% |", m.cpu_pct);
      md << b;
    }
    std::snprintf(b, sizeof b, " %.2f | %.2f | %.2f |\n", r.m[4].cpu_pct / r.m[0].cpu_pct,
                  r.m[4].cpu_pct / r.m[3].cpu_pct, r.m[4].cpu_pct / floor1.cpu_pct);
    md << b;
  }
  md << "\nVoluntary context switches per second of the publisher's threads other than the pacing thread(s)"
        " (Fast DDS's event and receive threads, `run`'s main thread; /proc/PID/task/*/status over the same"
        " window); the floor's column is its one thread's.\n\n";
  // One table per measure: a row per axis count, the floor's column first ("-" where it has none).
  const auto table = [&](double Measure::*field, bool floor_column) {
    head("");
    for (const auto& r : rows) {
      if (floor_column)
        std::snprintf(b, sizeof b, "| %d | %.0f |", r.n, floor1.other_switches_per_s + floor1.pacing_switches_per_s);
      else
        std::snprintf(b, sizeof b, "| %d | - |", r.n);
      md << b;
      for (const auto& m : r.m) {
        std::snprintf(b, sizeof b, " %.0f |", m.*field);
        md << b;
      }
      md << "\n";
    }
  };
  table(&Measure::other_switches_per_s, true);
  md << "\nThe same, the pacing thread(s): `run`'s sample threads (named ve-...), the bare writer's main thread.\n\n";
  table(&Measure::pacing_switches_per_s, true);
  md << "\nSamples published per second (over the publisher's whole life, start-up included).\n\n";
  table(&Measure::pub_per_s, false);
  std::printf("%s", md.str().c_str());
  std::ofstream(out_file) << md.str();
  std::fprintf(stderr, "written to %s\n", out_file.c_str());
  fs::remove_all(dir);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  std::vector<int> axis_counts{1, 2, 4, 8, 16};
  double window = 10.0, warmup = 3.0;
  int domain = 97;
  const fs::path src = VE_BENCH_SOURCE_DIR;
  std::string out_file = (src / "tests/bench/results/scale.md").string();
  std::string mode = "axes";
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
    else if (k == "--mode" && (v == "axes" || v == "deadline")) mode = v;
    else {
      std::fprintf(stderr, "usage: bench_scale [--mode axes|deadline] [--axes 1,2,4,8,16] [--window S] [--warmup S] "
                           "[--domain D] [--out FILE]\n");
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
  auto measure = [&](const std::vector<std::string>& pub_args, bool with_sub, const std::string& tag,
                     const std::vector<std::pair<std::string, std::string>>& env = {}) {
    Measure m;
    Child sub;
    const std::string sub_out = (dir / (tag + ".sub.out")).string();
    if (with_sub) {
      sub = spawn({VE_BARE_READER, d, "100000"}, sub_out, (dir / (tag + ".sub.err")).string(), profiles);
      wait_for_line(sub_out, "READY", 10);
    }
    const std::string pub_out = (dir / (tag + ".out")).string(), pub_err = (dir / (tag + ".err")).string();
    const auto t_spawn = std::chrono::steady_clock::now();
    Child pub = spawn(pub_args, pub_out, pub_err, profiles, env);
    std::this_thread::sleep_for(std::chrono::duration<double>(warmup));
    const double p0 = cpu_seconds(pub.pid), s0 = with_sub ? cpu_seconds(sub.pid) : 0;
    const unsigned long long r0 = with_sub ? received(sub_out) : 0;
    const TaskSwitches w0 = task_switches(pub.pid);
    const auto t0 = std::chrono::steady_clock::now();
    std::this_thread::sleep_for(std::chrono::duration<double>(window));
    const double p1 = cpu_seconds(pub.pid), s1 = with_sub ? cpu_seconds(sub.pid) : 0;
    const TaskSwitches w1 = task_switches(pub.pid);
    const double dt = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    m.pacing_switches_per_s = switches_per_s(w0.pacing, w1.pacing, dt);
    m.other_switches_per_s = switches_per_s(w0.other, w1.other, dt);
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
    std::fprintf(stderr, "  %-22s cpu %6.1f %% published %.0f/s switches/s %.0f + %.0f%s\n", tag.c_str(), m.cpu_pct,
                 m.pub_per_s, m.pacing_switches_per_s, m.other_switches_per_s,
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
  if (mode == "deadline") return deadline_table(measure, floor1, axis_counts, src, dir, d, seconds, window, warmup,
                                                rate, load_before, out_file);
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
        " all axes in one sample thread (`realtime.sample_loop: shared`, the default: one wake-up per tick for"
        " every axis) and one state writer for them (`dds.state_writer: per_group`, the default).\n"
     << "* `run`, thread per axis: the same with `realtime.sample_loop: per_axis`, one sample thread and one"
        " state writer per axis (the design before the shared loop), measured in the same run.\n"
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
