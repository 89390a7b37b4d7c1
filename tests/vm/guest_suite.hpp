// The host side of a SocketCAN VM test: boots the VM (tests/vm/prepare.sh,
// run_in_vm.sh) and runs the given guest tests of this same binary inside it with
// VE_IN_VM=1, then reports the guest's log and result. Used by every *_vm_test.cpp.
#pragma once

#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "../integration/process.hpp"
#include "../integration/temp_dir.hpp"

namespace ve::test {

inline bool in_vm() { return std::getenv("VE_IN_VM") != nullptr; }

inline std::string slurp(const std::string& path) {
  std::ifstream f(path);
  std::stringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

/// Runs `gtest_filter` in the VM. `domains_held`: the DDS domains (comma-separated)
/// this process holds for the guest (its network is its own loopback, but no test
/// uses a domain it has not reserved). The guest may run `guest_s` seconds.
inline void run_guest_suite(const std::string& run_dir_prefix, const std::string& gtest_filter,
                            const std::string& domains_held, int guest_s) {
  const std::string src = VE_SOURCE_DIR;
  const std::string cache = VE_VM_CACHE;
  std::filesystem::create_directories(cache);
  // What this run writes is its own (two test runs of one build tree may boot a VM
  // each at the same time): a fresh directory, visible at the same path in the guest.
  const TempDir run_dir(run_dir_prefix);
  ASSERT_FALSE(run_dir.path.empty());
  const std::string out = run_dir.path.string();
  // The VM and what prepares it run as children of this test (integration/process.hpp):
  // they end with it, also when it fails or is killed. The cache is prepared by one
  // run at a time (flock).
  ChildProcess prepare({"/usr/bin/flock", cache + ".lock", "/bin/sh", src + "/tests/vm/prepare.sh", cache},
                       out + "/prepare.log");
  const int p = prepare.wait_exit(std::chrono::seconds(280));
  if (p == 77) GTEST_SKIP() << "SocketCAN VM unavailable: " << slurp(out + "/prepare.log");
  ASSERT_EQ(p, 0) << slurp(out + "/prepare.log");

  char exe[4096] = {};
  ASSERT_GT(readlink("/proc/self/exe", exe, sizeof exe - 1), 0);
  const std::string script = out + "/guest.sh";
  {
    std::ofstream s(script);
    s << "#!/bin/sh\n"
      << "export VE_IN_VM=1 PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin HOME=/tmp\n"
      << "export VE_TEST_DDS_DOMAINS_HELD=" << domains_held << "\n"
      // The guest receives the state stream: its socket buffers as the package sets
      // them on every such host (docs/dds-interface.md, Buffer sizes). With the
      // kernel's default cap (208 KiB, 20 ms of two axes at 4 kHz) the emulated
      // guest's DDS readers lost samples whenever their thread waited for a core.
      << "sysctl -q -p " << src << "/deploy/sysctl/60-virtual-encoder.conf\n"
      << "cd " << out << "\n"
      << exe << " --gtest_filter='" << gtest_filter << "' --gtest_color=no > " << out << "/guest.log 2>&1\n"
      << "echo $? > " << out << "/guest.rc\n"
      << "sync\n";
  }
  const auto t0 = std::chrono::steady_clock::now();
  ChildProcess vm({"/bin/sh", src + "/tests/vm/run_in_vm.sh", cache, script, std::to_string(guest_s)},
                  out + "/run.log");
  const int r = vm.wait_exit(std::chrono::seconds(guest_s + 30));
  const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (r == 77) GTEST_SKIP() << slurp(out + "/run.log");
  const std::string log = slurp(out + "/guest.log");
  std::printf("---- guest (VM %.1f s) ----\n%s---- end guest ----\n", secs, log.c_str());
  ASSERT_EQ(r, 0) << slurp(out + "/run.log") << "\nconsole:\n" << slurp(out + "/console.log");
  const std::string rc = slurp(out + "/guest.rc");
  ASSERT_FALSE(rc.empty()) << "the guest wrote no result; console:\n" << slurp(out + "/console.log");
  EXPECT_EQ(std::atoi(rc.c_str()), 0) << "guest tests failed (log above)";
  EXPECT_NE(log.find("[  PASSED  ]"), std::string::npos);
}

}  // namespace ve::test
