// The product's participant receives over UDPv4 only (DdsContext::create): it
// announces no shared-memory locator, so no peer keeps a shared-memory port of
// it that a restarted process would reuse, while a participant with Fast DDS's
// defaults announces both. Checked from the outside: a plain Fast DDS
// participant (the defaults a local consumer has) lists the locators each one
// announces in discovery.
#include <gtest/gtest.h>

#include <fastdds/dds/domain/DomainParticipant.hpp>
#include <fastdds/dds/domain/DomainParticipantFactory.hpp>
#include <fastdds/dds/domain/DomainParticipantListener.hpp>

#include <chrono>
#include <cstdio>
#include <map>
#include <mutex>
#include <string>

#include "app/dds_io.hpp"
#include "process.hpp"
#include "test_domain.hpp"

namespace {

namespace fdds = eprosima::fastdds::dds;
using namespace std::chrono_literals;

struct Announced {
  bool seen = false;
  int udp = 0, shm = 0;
};

class Observer : public fdds::DomainParticipantListener {
 public:
  void on_participant_discovery(fdds::DomainParticipant*,
                                eprosima::fastrtps::rtps::ParticipantDiscoveryInfo&& info) override {
    if (info.status != eprosima::fastrtps::rtps::ParticipantDiscoveryInfo::DISCOVERED_PARTICIPANT) return;
    Announced a;
    a.seen = true;
    auto count = [&a](const eprosima::fastrtps::rtps::Locator_t& l) {
      if (l.kind == LOCATOR_KIND_UDPv4) ++a.udp;
      if (l.kind == LOCATOR_KIND_SHM) ++a.shm;
    };
    for (const auto& l : info.info.metatraffic_locators.unicast) count(l);
    for (const auto& l : info.info.default_locators.unicast) count(l);
    std::lock_guard<std::mutex> lock(mutex_);
    by_name_[info.info.m_participantName.to_string()] = a;
  }
  Announced get(const std::string& name) {
    std::lock_guard<std::mutex> lock(mutex_);
    auto it = by_name_.find(name);
    return it == by_name_.end() ? Announced{} : it->second;
  }

 private:
  std::mutex mutex_;
  std::map<std::string, Announced> by_name_;
};

TEST(DdsParticipantLocators, ProductReceivesOverUdpOnlyAndAConsumerWithDefaultsOverBoth) {
  const int domain = ve::test::dds_domain();
  auto* factory = fdds::DomainParticipantFactory::get_instance();
  Observer observer;
  fdds::DomainParticipantQos oq = fdds::PARTICIPANT_QOS_DEFAULT;
  oq.name("locators-observer");
  fdds::DomainParticipant* plain = factory->create_participant(domain, oq, &observer);
  ASSERT_NE(plain, nullptr);

  std::string error;
  ve::app::DdsOptions product;
  product.domain = domain;
  product.participant_name = "locators-product";
  auto product_ctx = ve::app::DdsContext::create(product, error);
  ASSERT_TRUE(product_ctx) << error;
  ve::app::DdsOptions consumer = product;
  consumer.participant_name = "locators-consumer";
  consumer.receive_over_shm = true;
  auto consumer_ctx = ve::app::DdsContext::create(consumer, error);
  ASSERT_TRUE(consumer_ctx) << error;

  ASSERT_TRUE(ve::test::wait_until(
      [&] { return observer.get("locators-product").seen && observer.get("locators-consumer").seen; }, 20s))
      << "the observer did not discover both participants";
  const Announced p = observer.get("locators-product");
  EXPECT_GT(p.udp, 0) << "the product participant announces UDPv4 locators";
  EXPECT_EQ(p.shm, 0) << "the product participant announces no shared-memory locator";
  // A peer on the same host with Fast DDS's defaults is reached over shared
  // memory alone: Fast DDS 2.9 keeps only its shared-memory locators (the UDPv4
  // ones are dropped on reception), so a dead port of it is the only way there.
  const Announced c = observer.get("locators-consumer");
  EXPECT_GT(c.shm, 0) << "a participant with Fast DDS's defaults announces shared memory";
  std::printf("[ figures  ] locators seen by a default participant: product %d UDPv4 / %d SHM, consumer with "
              "defaults %d UDPv4 / %d SHM\n",
              p.udp, p.shm, c.udp, c.shm);

  consumer_ctx.reset();
  product_ctx.reset();
  EXPECT_EQ(plain->set_listener(nullptr), eprosima::fastrtps::types::ReturnCode_t::RETCODE_OK);
  EXPECT_EQ(factory->delete_participant(plain), eprosima::fastrtps::types::ReturnCode_t::RETCODE_OK);
}

}  // namespace
