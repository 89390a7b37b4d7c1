// A bare Fast DDS 2.9 reader of ve/encoder_state: what a drive controller's
// integrator writes from docs/dds-integration.md, with nothing of the product's
// code (only the types generated from idl/VirtualEncoder.idl). It stands in for a
// consumer in the publisher crash test (tests/integration/publisher_kill_test.cpp).
//
//   ve_bare_reader DOMAIN DURATION_S [--defaults]
//
// Without --defaults: the documented configuration. The profiles come from
// FASTRTPS_DEFAULT_PROFILES_FILE (deploy/dds-profiles.xml, installed as
// /usr/share/virtual-encoder/dds-profiles.xml); the participant is made from the
// profile "ve_participant" and the reader from "ve_state_reader". Missing profiles
// are an error (exit 1).
// With --defaults: Fast DDS's default participant (shared memory and UDPv4) and a
// best-effort reader with Fast DDS's other defaults: a consumer that configured
// nothing.
//
// Output (stdout, one line each, flushed):
//   READY                                             the reader exists
//   RESUME rx_ns=T seq=S source_ns=U silent_ms=G      first sample after a silence of
//       at least 50 ms, or a sequence number that did not rise (a new publisher),
//       or the very first sample (silent_ms=-1); T is CLOCK_REALTIME at reception
//   MATCHED rx_ns=T current=N change=C                a writer matched (C = 1) or went (C = -1)
//   ALIVE rx_ns=T received=N                          every 250 ms
//   END received=N resumes=R                          at a clean end
// Ends after DURATION_S or at SIGINT/SIGTERM, deleting every entity: exit 0.
#include <signal.h>
#include <time.h>

#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <mutex>
#include <string>
#include <thread>

#include <fastdds/dds/domain/DomainParticipant.hpp>
#include <fastdds/dds/domain/DomainParticipantFactory.hpp>
#include <fastdds/dds/subscriber/DataReader.hpp>
#include <fastdds/dds/subscriber/DataReaderListener.hpp>
#include <fastdds/dds/subscriber/SampleInfo.hpp>
#include <fastdds/dds/subscriber/Subscriber.hpp>
#include <fastdds/dds/subscriber/qos/DataReaderQos.hpp>
#include <fastdds/dds/topic/Topic.hpp>
#include <fastdds/dds/topic/TypeSupport.hpp>
#include <fastrtps/types/DynamicDataFactory.h>
#include <fastrtps/types/DynamicTypeBuilderFactory.h>
#include <fastrtps/types/TypeObjectFactory.h>

#include "VirtualEncoderPubSubTypes.h"
#include "VirtualEncoderTypeObject.h"

namespace fdds = eprosima::fastdds::dds;
using eprosima::fastrtps::types::ReturnCode_t;

namespace {

std::atomic<bool> g_stop{false};

void on_signal(int) { g_stop.store(true); }

std::int64_t realtime_ns() {
  timespec ts{};
  clock_gettime(CLOCK_REALTIME, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1000000000LL + ts.tv_nsec;
}

class Listener : public fdds::DataReaderListener {
 public:
  void on_data_available(fdds::DataReader* reader) override {
    ve::dds::EncoderState s;
    fdds::SampleInfo info;
    while (reader->take_next_sample(&s, &info) == ReturnCode_t::RETCODE_OK) {
      if (!info.valid_data) continue;
      const std::int64_t now = realtime_ns();
      const bool first = received_.load() == 0;
      const std::int64_t silent_ns = first ? -1 : now - last_rx_ns_;
      if (first || silent_ns >= 50000000LL || s.sequence_number() <= last_seq_) {
        std::printf("RESUME rx_ns=%lld seq=%llu source_ns=%lld silent_ms=%.1f\n", static_cast<long long>(now),
                    static_cast<unsigned long long>(s.sequence_number()), static_cast<long long>(s.source_time_ns()),
                    first ? -1.0 : silent_ns * 1e-6);
        std::fflush(stdout);
        resumes_.fetch_add(1);
      }
      last_rx_ns_ = now;
      last_seq_ = s.sequence_number();
      received_.fetch_add(1);
    }
  }
  void on_subscription_matched(fdds::DataReader*, const fdds::SubscriptionMatchedStatus& st) override {
    std::printf("MATCHED rx_ns=%lld current=%d change=%d\n", static_cast<long long>(realtime_ns()), st.current_count,
                st.current_count_change);
    std::fflush(stdout);
  }
  std::uint64_t received() const { return received_.load(); }
  std::uint64_t resumes() const { return resumes_.load(); }

 private:
  // Listener thread only.
  std::int64_t last_rx_ns_ = 0;
  std::uint64_t last_seq_ = 0;
  std::atomic<std::uint64_t> received_{0};
  std::atomic<std::uint64_t> resumes_{0};
};

}  // namespace

int main(int argc, char** argv) {
  if (argc < 3) {
    std::fprintf(stderr, "usage: %s DOMAIN DURATION_S [--defaults]\n", argv[0]);
    return 2;
  }
  const int domain = std::atoi(argv[1]);
  // Fast DDS 2.9's type registries created and filled before the participant exists: a
  // discovered endpoint's TypeObject is built into them on the receive threads
  // (docs/dds-integration.md, "Type registries").
  eprosima::fastrtps::types::TypeObjectFactory::get_instance();
  eprosima::fastrtps::types::DynamicTypeBuilderFactory::get_instance();
  eprosima::fastrtps::types::DynamicDataFactory::get_instance();
  registerVirtualEncoderTypes();
  const double duration_s = std::atof(argv[2]);
  const bool defaults = argc > 3 && std::strcmp(argv[3], "--defaults") == 0;
  std::setvbuf(stdout, nullptr, _IOLBF, 0);
  struct sigaction sa {};
  sa.sa_handler = on_signal;
  sigaction(SIGINT, &sa, nullptr);
  sigaction(SIGTERM, &sa, nullptr);

  auto* factory = fdds::DomainParticipantFactory::get_instance();
  fdds::DomainParticipantQos pq;
  if (defaults) {
    factory->get_default_participant_qos(pq);
  } else {
    // FASTRTPS_DEFAULT_PROFILES_FILE, as a drive controller would be configured.
    const char* file = std::getenv("FASTRTPS_DEFAULT_PROFILES_FILE");
    if (file == nullptr || *file == '\0') {
      std::fprintf(stderr, "bare_reader: FASTRTPS_DEFAULT_PROFILES_FILE is not set (docs/dds-integration.md)\n");
      return 1;
    }
    factory->load_profiles();
    if (factory->get_participant_qos_from_profile("ve_participant", pq) != ReturnCode_t::RETCODE_OK) {
      std::fprintf(stderr, "bare_reader: no participant profile 've_participant' in %s\n", file);
      return 1;
    }
  }
  pq.name(defaults ? "bare-reader-defaults" : "bare-reader");
  fdds::DomainParticipant* participant = factory->create_participant(domain, pq);
  if (participant == nullptr) {
    std::fprintf(stderr, "bare_reader: cannot create a participant on domain %d\n", domain);
    return 1;
  }
  fdds::TypeSupport type(new ve::dds::EncoderStatePubSubType());
  type->auto_fill_type_information(false);
  type.register_type(participant);
  fdds::Topic* topic = participant->create_topic("ve/encoder_state", type.get_type_name(), fdds::TOPIC_QOS_DEFAULT);
  fdds::Subscriber* subscriber = participant->create_subscriber(fdds::SUBSCRIBER_QOS_DEFAULT);
  fdds::DataReaderQos rq;
  if (defaults) {
    subscriber->get_default_datareader_qos(rq);
    rq.reliability().kind = fdds::BEST_EFFORT_RELIABILITY_QOS;  // the writer offers best effort
  } else if (subscriber->get_datareader_qos_from_profile("ve_state_reader", rq) != ReturnCode_t::RETCODE_OK) {
    std::fprintf(stderr, "bare_reader: no data_reader profile 've_state_reader'\n");
    return 1;
  }
  Listener listener;
  fdds::DataReader* reader =
      topic == nullptr ? nullptr : subscriber->create_datareader(topic, rq, &listener,
                                       fdds::StatusMask::data_available() << fdds::StatusMask::subscription_matched());
  int rc = 0;
  if (reader == nullptr) {
    std::fprintf(stderr, "bare_reader: cannot create the reader\n");
    rc = 1;
  } else {
    std::printf("READY\n");
    const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(duration_s);
    auto next_alive = std::chrono::steady_clock::now();
    while (!g_stop.load() && std::chrono::steady_clock::now() < end) {
      if (std::chrono::steady_clock::now() >= next_alive) {
        std::printf("ALIVE rx_ns=%lld received=%llu\n", static_cast<long long>(realtime_ns()),
                    static_cast<unsigned long long>(listener.received()));
        next_alive += std::chrono::milliseconds(250);
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    reader->set_listener(nullptr);
    subscriber->delete_datareader(reader);
  }
  participant->delete_contained_entities();
  factory->delete_participant(participant);
  std::printf("END received=%llu resumes=%llu\n", static_cast<unsigned long long>(listener.received()),
              static_cast<unsigned long long>(listener.resumes()));
  return rc;
}
