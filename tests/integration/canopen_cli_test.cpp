// `virtual-encoder eds` and `check` on machine files with a `canopen:` block, as a user
// runs them (the program as a child process). `run` with a node needs a CAN interface:
// tests/vm/canopen_vm_test.cpp.
#include <gtest/gtest.h>

#include <chrono>
#include <fstream>
#include <sstream>
#include <string>

#include "process.hpp"
#include "temp_dir.hpp"

namespace {

const std::string kBin = VE_BINARY;

std::string slurp(const std::string& path) {
  std::ifstream f(path);
  std::stringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

struct Result {
  int code = -1;
  std::string out, err;
};

Result run(const ve::test::TempDir& dir, const std::vector<std::string>& args) {
  std::vector<std::string> argv{kBin};
  argv.insert(argv.end(), args.begin(), args.end());
  ve::test::ChildProcess p(argv, dir.file("out.txt"), dir.file("err.txt"));
  Result r;
  r.code = p.wait_exit(std::chrono::seconds(60));
  r.out = slurp(dir.file("out.txt"));
  r.err = slurp(dir.file("err.txt"));
  return r;
}

std::string machine(const std::string& y_canopen) {
  return "machine: co\naxes:\n"
         "  - name: x\n    motor: " VE_SOURCE_DIR "/config/motors/sim-12mm.yaml\n"
         "    canopen: {interface: can0, node_id: 12, bitrate_kbps: 500, measuring_step_nm: 100, transmission_type: 2}\n"
         "  - name: y\n    motor: " VE_SOURCE_DIR "/config/motors/sim-12mm.yaml\n" +
         y_canopen;
}

}  // namespace

TEST(CanopenCli, EdsDescribesTheAxisNode) {
  ve::test::TempDir dir("ve_canopen_cli");
  const std::string m = dir.write("m.yaml", machine(""));
  auto r = run(dir, {"eds", "--config", m, "--axis", "x"});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("[1000]"), std::string::npos);
  EXPECT_NE(r.out.find("DefaultValue=0x00080196"), std::string::npos) << "CiA 406 absolute linear encoder";
  EXPECT_NE(r.out.find("BaudRate_500=1"), std::string::npos);
  EXPECT_NE(r.out.find("[6501]\nParameterName=Measuring step\nObjectType=0x7\nDataType=0x0007\nAccessType=ro\n"
                       "DefaultValue=0x00000064"),
            std::string::npos)
      << r.out;
  EXPECT_NE(r.out.find("[1800sub2]\nParameterName=Transmission type\nObjectType=0x7\nDataType=0x0005\nAccessType=rw\n"
                       "DefaultValue=0x02"),
            std::string::npos);
  // Without --axis: the first axis with a node; --out writes the file.
  r = run(dir, {"eds", "--config", m, "--out", dir.file("x.eds")});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(slurp(dir.file("x.eds")).find("FileName=x.eds"), std::string::npos);
  // An axis without a node, and one that does not exist: usage errors naming them.
  r = run(dir, {"eds", "--config", m, "--axis", "y"});
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.err.find("axis 'y' has no canopen: block"), std::string::npos) << r.err;
  r = run(dir, {"eds", "--config", m, "--axis", "z"});
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.err.find("no axis 'z'"), std::string::npos) << r.err;
  r = run(dir, {"eds", "--help"});
  EXPECT_EQ(r.code, 0);
  for (const char* opt : {"--config", "--axis", "--out", "--log-level"}) EXPECT_NE(r.out.find(opt), std::string::npos) << opt;
}

TEST(CanopenCli, CheckReportsTheBlockWithFileAndLine) {
  ve::test::TempDir dir("ve_canopen_cli");
  const std::string m = dir.write("m.yaml", machine("    canopen: {interface: can0, node_id: 12, cyclic_timer_ms: -1}\n"));
  auto r = run(dir, {"check", "--config", m});
  EXPECT_EQ(r.code, 1);
  const std::string all = r.out + r.err;
  EXPECT_NE(all.find(m + ":8:"), std::string::npos) << all;
  EXPECT_NE(all.find("axes[1].canopen.node_id: duplicate node id 12 on interface 'can0'"), std::string::npos) << all;
  EXPECT_NE(all.find("axes[1].canopen.cyclic_timer_ms: -1 out of range [0, 65535] ms"), std::string::npos) << all;
  const std::string ok = dir.write("ok.yaml", machine("    canopen: {interface: can0, node_id: 13}\n"));
  r = run(dir, {"check", "--config", ok});
  EXPECT_EQ(r.code, 0) << r.out << r.err;
}
