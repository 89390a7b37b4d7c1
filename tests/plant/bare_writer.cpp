// A bare Fast DDS 2.9 writer of ve/encoder_state, for the scale benchmark
// (tests/plant/scale_bench.cpp): one thread wakes at a fixed rate, paced as the
// product's sample threads are (ve::drivers::sleep_until, drivers/pacing.hpp), and
// writes N samples per wake-up, one per axis instance (axis_id 1..N), through one
// DataWriter. No estimator, no per-axis thread: what the same number of writes costs
// through Fast DDS alone.
//
//   ve_bare_writer DOMAIN AXES [--rate HZ] [--duration S] [--order fixed|alternate]
//                  [--writers one|per_axis] [--deadline on|off]
//
// --order: the axes in the order 1..N every wake-up (fixed, the default), or 1..N then
// N..1 and so on (alternate, as the product's shared sample loop writes its group).
// --writers: one keyed writer for all axes (the default), or one writer per axis.
// --deadline off: the writer offers no deadline (the profile's 5 ms removed), to
// measure what the offered deadline costs.
//
// The participant is made from the profile "ve_participant" and the writer from
// "ve_state_writer" (FASTRTPS_DEFAULT_PROFILES_FILE, deploy/dds-profiles.xml: UDPv4 only,
// best effort, keep last 1, a 5 ms offered deadline, as the product's state writers);
// missing profiles are an error (exit 1); its resource limits are raised to AXES instances.
// Defaults: 4000 Hz, until SIGINT/SIGTERM.
// Prints "READY", and at the end "END written=W failed=F".
#include <csignal>
#include <time.h>

#include <atomic>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <thread>
#include <vector>

#include <fastdds/dds/domain/DomainParticipant.hpp>
#include <fastdds/dds/domain/DomainParticipantFactory.hpp>
#include <fastdds/dds/publisher/DataWriter.hpp>
#include <fastdds/dds/publisher/Publisher.hpp>
#include <fastdds/dds/publisher/qos/DataWriterQos.hpp>
#include <fastdds/dds/topic/Topic.hpp>
#include <fastdds/dds/topic/TypeSupport.hpp>
#include <fastrtps/types/DynamicDataFactory.h>
#include <fastrtps/types/DynamicTypeBuilderFactory.h>
#include <fastrtps/types/TypeObjectFactory.h>

#include "VirtualEncoderPubSubTypes.h"
#include "VirtualEncoderTypeObject.h"
#include "pacing.hpp"  // drivers/pacing.hpp

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
}  // namespace

int main(int argc, char** argv) {
  if (argc < 3) {
    std::fprintf(stderr, "usage: ve_bare_writer DOMAIN AXES [--rate HZ] [--duration S] [--order fixed|alternate] "
                         "[--writers one|per_axis] [--deadline on|off]\n");
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
  const int axes = std::atoi(argv[2]);
  double rate = 4000.0, duration = 0.0;
  bool alternate = false, writer_per_axis = false, deadline = true;
  for (int i = 3; i + 1 < argc; i += 2) {
    const std::string k = argv[i], v = argv[i + 1];
    if (k == "--rate") rate = std::atof(v.c_str());
    else if (k == "--duration") duration = std::atof(v.c_str());
    else if (k == "--order" && (v == "fixed" || v == "alternate")) alternate = v == "alternate";
    else if (k == "--writers" && (v == "one" || v == "per_axis")) writer_per_axis = v == "per_axis";
    else if (k == "--deadline" && (v == "on" || v == "off")) deadline = v == "on";
    else return 2;
  }
  if (axes < 1 || rate <= 0) return 2;
  std::signal(SIGINT, on_signal);
  std::signal(SIGTERM, on_signal);

  auto* factory = fdds::DomainParticipantFactory::get_instance();
  factory->load_profiles();
  fdds::DomainParticipantQos pq;
  if (factory->get_participant_qos_from_profile("ve_participant", pq) != ReturnCode_t::RETCODE_OK) {
    std::fprintf(stderr, "bare_writer: no participant profile 've_participant' (FASTRTPS_DEFAULT_PROFILES_FILE)\n");
    return 1;
  }
  pq.name("bare-writer");
  fdds::DomainParticipant* participant = factory->create_participant(domain, pq);
  if (participant == nullptr) return 1;
  fdds::TypeSupport type(new ve::dds::EncoderStatePubSubType());
  type.register_type(participant);
  fdds::Topic* topic = participant->create_topic("ve/encoder_state", type.get_type_name(), fdds::TOPIC_QOS_DEFAULT);
  fdds::Publisher* publisher = participant->create_publisher(fdds::PUBLISHER_QOS_DEFAULT);
  fdds::DataWriterQos wq;
  if (publisher->get_datawriter_qos_from_profile("ve_state_writer", wq) != ReturnCode_t::RETCODE_OK) {
    std::fprintf(stderr, "bare_writer: no data_writer profile 've_state_writer'\n");
    return 1;
  }
  if (!deadline) wq.deadline().period = eprosima::fastrtps::c_TimeInfinite;
  // One writer, AXES instances: Fast DDS 2.9 keeps at most 10 instances per writer by default
  // (the profile sets no resource limits). Or one writer per axis, one instance each.
  const int per_writer = writer_per_axis ? 1 : axes;
  wq.resource_limits().max_instances = per_writer;
  wq.resource_limits().max_samples_per_instance = 1;
  wq.resource_limits().max_samples = per_writer;
  wq.resource_limits().allocated_samples = per_writer;
  std::vector<fdds::DataWriter*> writers;
  for (int i = 0; i < (writer_per_axis ? axes : 1); ++i) {
    writers.push_back(publisher->create_datawriter(topic, wq));
    if (writers.back() == nullptr) return 1;
  }
  std::printf("READY\n");
  std::fflush(stdout);

  const auto period_ns = static_cast<std::int64_t>(1e9 / rate);
  const std::int64_t start = ve::drivers::monotonic_ns();
  const std::int64_t end = duration > 0 ? start + static_cast<std::int64_t>(duration * 1e9) : 0;
  std::uint64_t written = 0, failed = 0, seq = 0;
  ve::dds::EncoderState s;
  std::int64_t due = start;
  while (!g_stop.load(std::memory_order_relaxed)) {
    due += period_ns;
    if (!ve::drivers::sleep_until(due, g_stop)) break;
    if (end != 0 && due >= end) break;
    ++seq;
    const std::int64_t now = realtime_ns();
    for (int k = 0; k < axes; ++k) {
      const int a = alternate && (seq % 2 == 0) ? axes - k : k + 1;
      fdds::DataWriter* writer = writers[writer_per_axis ? a - 1 : 0];
      s.axis_id(static_cast<std::uint32_t>(a));
      s.sequence_number(seq);
      s.sample_time_ns(due);
      s.position_m(0.5 + 1e-6 * static_cast<double>(seq % 1000));
      s.position_counts(static_cast<std::int64_t>(s.position_m() * 1e7));
      s.velocity_mps(0.001);
      s.position_std_m(1e-7);
      s.velocity_std_mps(1e-5);
      s.status(0x3);
      s.source_time_ns(now);
      s.publish_time_ns(realtime_ns());
      if (writer->write(&s)) ++written;
      else ++failed;
    }
  }
  participant->delete_contained_entities();
  factory->delete_participant(participant);
  std::printf("END written=%llu failed=%llu\n", static_cast<unsigned long long>(written),
              static_cast<unsigned long long>(failed));
  return 0;
}
