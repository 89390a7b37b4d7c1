// What `virtual-encoder run` announces about its types in discovery, as another Fast DDS
// participant sees it. By default no TypeObject: a Fast DDS 2.9 participant that
// discovers an endpoint carrying a complete TypeObject builds a DynamicType from it on
// its receive threads, in a type registry whose writes are not thread-safe, so a
// product that announced them would expose every drive controller that discovers it
// to that race (the crash was seen in the product's own processes). VE_DDS_TYPE_OBJECT=1
// turns the announcement on for generic tools that need it.
#include <gtest/gtest.h>

#include <fastdds/dds/domain/DomainParticipant.hpp>
#include <fastdds/dds/domain/DomainParticipantFactory.hpp>
#include <fastdds/dds/domain/DomainParticipantListener.hpp>
#include <fastrtps/types/TypeObject.h>

#include <csignal>
#include <mutex>
#include <string>
#include <vector>

#include "process.hpp"
#include "speed.hpp"
#include "temp_dir.hpp"
#include "test_domain.hpp"

namespace {

using namespace std::chrono_literals;
using ve::test::ChildProcess;
using ve::test::patience;
using ve::test::wait_until;
namespace fdds = eprosima::fastdds::dds;

/// What one discovered writer carried.
struct SeenWriter {
  std::string topic;
  std::string type_name;
  bool has_type_id = false;
  bool has_type_object = false;
  int type_object_kind = 0;  // EK_MINIMAL / EK_COMPLETE when has_type_object
};

/// A plain participant (UDPv4, as the product's) that records every writer it discovers
/// and every type it is handed.
class Watcher : public fdds::DomainParticipantListener {
 public:
  explicit Watcher(int domain) {
    fdds::DomainParticipantQos pq = fdds::PARTICIPANT_QOS_DEFAULT;
    pq.name("integration-test-type-object");
    participant_ = fdds::DomainParticipantFactory::get_instance()->create_participant(
        static_cast<fdds::DomainId_t>(domain), pq, this, fdds::StatusMask::none());
  }
  ~Watcher() override {
    if (participant_ != nullptr) fdds::DomainParticipantFactory::get_instance()->delete_participant(participant_);
  }
  bool ok() const { return participant_ != nullptr; }

  void on_publisher_discovery(fdds::DomainParticipant*, eprosima::fastrtps::rtps::WriterDiscoveryInfo&& info) override {
    if (info.status != eprosima::fastrtps::rtps::WriterDiscoveryInfo::DISCOVERED_WRITER) return;
    SeenWriter w;
    w.topic = info.info.topicName().to_string();
    w.type_name = info.info.typeName().to_string();
    w.has_type_id = info.info.has_type_id() && info.info.type_id().m_type_identifier._d() != 0;
    w.has_type_object = info.info.has_type() && info.info.type().m_type_object._d() != 0;
    if (w.has_type_object) w.type_object_kind = info.info.type().m_type_object._d();
    std::lock_guard<std::mutex> lock(mutex_);
    writers_.push_back(w);
  }

  bool find(const std::string& topic, SeenWriter& out) {
    std::lock_guard<std::mutex> lock(mutex_);
    for (const auto& w : writers_)
      if (w.topic == topic) {
        out = w;
        return true;
      }
    return false;
  }

 private:
  fdds::DomainParticipant* participant_ = nullptr;
  std::mutex mutex_;
  std::vector<SeenWriter> writers_;
};

std::vector<std::string> run_args(int domain, bool type_object) {
  std::vector<std::string> a{"/usr/bin/env"};
  if (type_object) a.push_back("VE_DDS_TYPE_OBJECT=1");
  const std::string config = std::string(VE_SOURCE_DIR) + "/tests/integration/data/standstill.yaml";
  for (const std::string& s :
       {std::string(VE_BINARY), std::string("run"), std::string("--config"), config, std::string("--domain"),
        std::to_string(domain), std::string("--duration"), std::string("60")})
    a.push_back(s);
  return a;
}

SeenWriter discover_state_writer(bool type_object) {
  const int domain = ve::test::dds_domain();
  ve::test::TempDir dir;
  Watcher watcher(domain);
  EXPECT_TRUE(watcher.ok());
  ChildProcess pub(run_args(domain, type_object), (dir.path / "run.log").string());
  EXPECT_TRUE(pub.started());
  SeenWriter w;
  EXPECT_TRUE(wait_until([&] { return watcher.find("ve/encoder_state", w); }, patience(15s)))
      << "the encoder's state writer was not discovered\n"
      << pub.log();
  pub.signal(SIGTERM);
  EXPECT_EQ(pub.wait_exit(patience(10s)), 0) << pub.log();
  return w;
}

TEST(DdsTypeObject, NotAnnouncedByDefault) {
  const SeenWriter w = discover_state_writer(false);
  EXPECT_EQ(w.type_name, "ve::dds::EncoderState");
  EXPECT_FALSE(w.has_type_object) << "kind " << w.type_object_kind;
  EXPECT_FALSE(w.has_type_id);
}

TEST(DdsTypeObject, AnnouncedOnRequest) {
  const SeenWriter w = discover_state_writer(true);
  EXPECT_EQ(w.type_name, "ve::dds::EncoderState");
  EXPECT_TRUE(w.has_type_object);
  EXPECT_EQ(w.type_object_kind, eprosima::fastrtps::types::EK_COMPLETE);
}

}  // namespace
