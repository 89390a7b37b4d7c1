// `dds.statistics` in the machine file turns on Fast DDS statistics topics, the
// ones DDS monitoring tools read: another participant discovers their writers.
#include <gtest/gtest.h>

#include <atomic>
#include <mutex>
#include <set>
#include <string>

#include <fastdds/dds/domain/DomainParticipant.hpp>
#include <fastdds/dds/domain/DomainParticipantFactory.hpp>
#include <fastdds/dds/domain/DomainParticipantListener.hpp>

#include "process.hpp"
#include "temp_dir.hpp"
#include "test_domain.hpp"

namespace {

using namespace std::chrono_literals;
namespace fdds = eprosima::fastdds::dds;

class Topics : public fdds::DomainParticipantListener {
 public:
  void on_publisher_discovery(fdds::DomainParticipant*, eprosima::fastrtps::rtps::WriterDiscoveryInfo&& info) override {
    std::lock_guard<std::mutex> lock(mutex);
    names.insert(info.info.topicName().to_string());
  }
  bool has(const std::string& t) {
    std::lock_guard<std::mutex> lock(mutex);
    return names.count(t) > 0;
  }
  std::mutex mutex;
  std::set<std::string> names;
};

TEST(DdsStatistics, MachineFileTurnsOnTheNamedStatisticsTopics) {
  const int domain = ve::test::dds_domain();
  ve::test::TempDir dir;
  Topics topics;
  auto* factory = fdds::DomainParticipantFactory::get_instance();
  fdds::DomainParticipant* p =
      factory->create_participant(domain, fdds::PARTICIPANT_QOS_DEFAULT, &topics, fdds::StatusMask::none());
  ASSERT_NE(p, nullptr);
  ve::test::ChildProcess run({VE_BINARY, "run", "--config",
                              std::string(VE_SOURCE_DIR) + "/tests/integration/data/statistics.yaml", "--domain",
                              std::to_string(domain), "--duration", "20"},
                             (dir.path / "run.log").string());
  ASSERT_TRUE(run.started());
  EXPECT_TRUE(ve::test::wait_until([&] { return topics.has("ve/encoder_state"); }, 15s)) << run.log();
  EXPECT_TRUE(ve::test::wait_until([&] { return topics.has("_fastdds_statistics_publication_throughput"); }, 15s))
      << run.log();
  EXPECT_TRUE(topics.has("_fastdds_statistics_history2history_latency"));
  EXPECT_FALSE(topics.has("_fastdds_statistics_network_latency")) << "only the configured topics";
  run.signal(SIGTERM);
  EXPECT_EQ(run.wait_exit(10s), 0) << run.log();
  p->delete_contained_entities();
  factory->delete_participant(p);
}

}  // namespace
