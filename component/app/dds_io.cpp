#include "dds_io.hpp"

#include "deadline_periods.hpp"
#include "pacing.hpp"  // drivers/pacing.hpp: the time of day of a gap

#include <algorithm>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdlib>
#include <deque>
#include <fstream>
#include <iterator>
#include <mutex>
#include <thread>
#include <tuple>
#include <type_traits>

#include <fastdds/dds/domain/DomainParticipant.hpp>
#include <fastdds/dds/domain/DomainParticipantFactory.hpp>
#include <fastdds/dds/publisher/DataWriter.hpp>
#include <fastdds/dds/publisher/DataWriterListener.hpp>
#include <fastdds/dds/publisher/Publisher.hpp>
#include <fastdds/dds/publisher/qos/DataWriterQos.hpp>
#include <fastdds/dds/subscriber/DataReader.hpp>
#include <fastdds/dds/subscriber/DataReaderListener.hpp>
#include <fastdds/dds/subscriber/SampleInfo.hpp>
#include <fastdds/dds/subscriber/Subscriber.hpp>
#include <fastdds/dds/subscriber/qos/DataReaderQos.hpp>
#include <fastdds/dds/topic/TypeSupport.hpp>
#include <fastdds/rtps/transport/UDPv4TransportDescriptor.h>
#include <fastdds/dds/log/Log.hpp>
#include <fastrtps/types/DynamicDataFactory.h>
#include <fastrtps/types/DynamicTypeBuilderFactory.h>
#include <fastrtps/types/TypeObjectFactory.h>
#include <spdlog/spdlog.h>

#include "VirtualEncoderPubSubTypes.h"
#include "VirtualEncoderTypeObject.h"

namespace fdds = eprosima::fastdds::dds;
using eprosima::fastrtps::types::ReturnCode_t;

namespace ve::app {

namespace {

/// The number of writers matched with a reader whose listener is attached after the
/// reader is created (so that no sample callback runs before the listener knows its
/// readers): a match made in between gave no callback, so once the listener is
/// attached the count is also read from the reader's status. A callback that comes
/// while that status is being read wins, being at least as new. Our mutex is never
/// held while Fast DDS is called.
class MatchCount {
 public:
  void on_callback(int current) {
    std::lock_guard<std::mutex> lock(mutex_);
    value_.store(current);
    ++callbacks_;
  }
  /// After set_listener(): the reader's own status, unless a callback overtook it.
  void sync(fdds::DataReader& reader) {
    std::uint64_t before;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      before = callbacks_;
    }
    fdds::SubscriptionMatchedStatus st;
    if (reader.get_subscription_matched_status(st) != ReturnCode_t::RETCODE_OK) return;
    std::lock_guard<std::mutex> lock(mutex_);
    if (callbacks_ == before) value_.store(st.current_count);
  }
  int load() const { return value_.load(); }

 private:
  std::mutex mutex_;
  std::uint64_t callbacks_ = 0;
  std::atomic<int> value_{0};
};

eprosima::fastrtps::Duration_t duration_ms(double ms) {
  const auto total_ns = static_cast<std::int64_t>(std::llround(ms * 1e6));
  return eprosima::fastrtps::Duration_t(static_cast<std::int32_t>(total_ns / 1000000000),
                                        static_cast<std::uint32_t>(total_ns % 1000000000));
}

std::int64_t steady_ns() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

double to_ms(const eprosima::fastrtps::Duration_t& d) {
  if (d == eprosima::fastrtps::c_TimeInfinite) return 0.0;
  return d.seconds * 1e3 + d.nanosec * 1e-6;
}

// Built-in QoS: the same values as deploy/dds-profiles.xml, used when the
// profiles are not loaded. Reasons: docs/dds-interface.md.

// No endpoint of the product uses data sharing (a shared-memory delivery path
// beside the transports, with the same dead-owner hazard: see udp_only()).
template <class Q>
void no_data_sharing(Q& q) {
  q.data_sharing().off();
}

/// Reliability, durability and history: keep last `depth`, or keep all for depth 0.
template <class Q>
void delivery(Q& q, fdds::ReliabilityQosPolicyKind reliability, fdds::DurabilityQosPolicyKind durability,
              std::int32_t depth) {
  q.reliability().kind = reliability;
  q.durability().kind = durability;
  q.history().kind = depth > 0 ? fdds::KEEP_LAST_HISTORY_QOS : fdds::KEEP_ALL_HISTORY_QOS;
  if (depth > 0) q.history().depth = depth;
}

/// A reader or writer of a topic with one instance per axis keeps every axis of a
/// machine (transport::kReaderMaxAxes), each with the history depth `depth`: Fast DDS
/// 2.9 keeps 10 instances by default, and a writer at that limit fails the write of
/// the 11th axis on.
template <class Q>
void per_axis_limits(Q& q, std::int32_t depth) {
  auto& r = q.resource_limits();
  r.max_instances = transport::kReaderMaxAxes;
  r.max_samples_per_instance = depth;
  r.max_samples = transport::kReaderMaxAxes * depth;
  r.allocated_samples = transport::kReaderAllocatedAxes * depth;
}

/// A periodic stream: its deadline, and liveliness AUTOMATIC (the participant
/// asserts it) with the lease and announcement period given: a lease of 1 s
/// offered, 2 s requested (offered <= requested), announcements every 0.5 s
/// (< lease, or Fast DDS refuses the writer).
template <class Q>
void periodic(Q& q, double deadline_ms, double lease_s, double announce_s) {
  q.deadline().period = duration_ms(deadline_ms);
  q.liveliness().kind = fdds::AUTOMATIC_LIVELINESS_QOS;
  q.liveliness().lease_duration = duration_ms(lease_s * 1e3);
  q.liveliness().announcement_period = duration_ms(announce_s * 1e3);
}

// The state stream: the newest sample is what a drive wants, a late retransmission
// is worth nothing, so best effort with a history of one.
void state_writer_defaults(fdds::DataWriterQos& q) {
  delivery(q, fdds::BEST_EFFORT_RELIABILITY_QOS, fdds::VOLATILE_DURABILITY_QOS, 1);
  periodic(q, 5.0, 1.0, 0.5);
  q.publish_mode().kind = fdds::SYNCHRONOUS_PUBLISH_MODE;
  q.endpoint().history_memory_policy = eprosima::fastrtps::rtps::PREALLOCATED_MEMORY_MODE;
}

// The reader's history per axis instance: 64 ms at 4 kHz. A listener drains it on
// the receive thread; a consumer that takes from its own loop may be descheduled
// for tens of ms without its history overwriting samples it has not taken yet.
void state_reader_defaults(fdds::DataReaderQos& q) {
  delivery(q, fdds::BEST_EFFORT_RELIABILITY_QOS, fdds::VOLATILE_DURABILITY_QOS, transport::kStateReaderDepth);
  per_axis_limits(q, transport::kStateReaderDepth);
  periodic(q, 10.0, 2.0, 1.0);
  q.endpoint().history_memory_policy = eprosima::fastrtps::rtps::PREALLOCATED_MEMORY_MODE;
}

// Diagnostics: 10 Hz, each one a summary worth having: reliable, newest only,
// never blocking the axis thread for long.
void diagnostics_writer_defaults(fdds::DataWriterQos& q) {
  delivery(q, fdds::RELIABLE_RELIABILITY_QOS, fdds::VOLATILE_DURABILITY_QOS, 1);
  q.reliability().max_blocking_time = duration_ms(1.0);
  per_axis_limits(q, 1);
  periodic(q, 500.0, 1.0, 0.5);
  q.publish_mode().kind = fdds::SYNCHRONOUS_PUBLISH_MODE;
}

void diagnostics_reader_defaults(fdds::DataReaderQos& q) {
  delivery(q, fdds::RELIABLE_RELIABILITY_QOS, fdds::VOLATILE_DURABILITY_QOS, 4);
  per_axis_limits(q, 4);
  periodic(q, 1000.0, 2.0, 1.0);
}

// Late joiners must learn what each axis is, and the last calibration status of
// each axis (progress and result; the writer never blocks the worker for long, a
// status is superseded a fraction of a second later): reliable, transient-local,
// last value per axis.
template <class Q>
void last_per_axis_defaults(Q& q) {
  delivery(q, fdds::RELIABLE_RELIABILITY_QOS, fdds::TRANSIENT_LOCAL_DURABILITY_QOS, 1);
  per_axis_limits(q, 1);
}

// Calibration commands: every request counts and none is replayed to a process
// that starts later: reliable, keep all, volatile.
template <class Q>
void calibration_command_defaults(Q& q) {
  delivery(q, fdds::RELIABLE_RELIABILITY_QOS, fdds::VOLATILE_DURABILITY_QOS, 0);
}

// Each topic once: the prefix of its profiles' names in deploy/dds-profiles.xml
// (<prefix>_writer, <prefix>_reader), its entity in DdsContext, and the built-in
// QoS of its writers and readers (used when the profiles are not loaded).
struct TopicQos {
  const char* profile_prefix;
  fdds::Topic* (DdsContext::*topic)() const;
  void (*writer_defaults)(fdds::DataWriterQos&);
  void (*reader_defaults)(fdds::DataReaderQos&);
};

/// The sample types of the rows of kTopics, in that order.
using TopicSamples = std::tuple<ve::dds::EncoderState, ve::dds::AxisDescription, ve::dds::Diagnostics,
                                ve::dds::CalibrationCommand, ve::dds::CalibrationStatus>;
const TopicQos kTopics[] = {
    {"ve_state", &DdsContext::state_topic, state_writer_defaults, state_reader_defaults},
    {"ve_description", &DdsContext::description_topic, last_per_axis_defaults, last_per_axis_defaults},
    {"ve_diagnostics", &DdsContext::diagnostics_topic, diagnostics_writer_defaults, diagnostics_reader_defaults},
    {"ve_calibration_command", &DdsContext::calibration_command_topic, calibration_command_defaults,
     calibration_command_defaults},
    {"ve_calibration_status", &DdsContext::calibration_status_topic, last_per_axis_defaults, last_per_axis_defaults},
};
static_assert(std::size(kTopics) == std::tuple_size_v<TopicSamples>);

template <class Sample, std::size_t I = 0>
constexpr std::size_t topic_index() {
  if constexpr (std::is_same_v<Sample, std::tuple_element_t<I, TopicSamples>>)
    return I;
  else
    return topic_index<Sample, I + 1>();
}

template <class Sample>
const TopicQos& topic_qos() {
  return kTopics[topic_index<Sample>()];
}

template <class Sample>
fdds::Topic* topic_of(const DdsContext& ctx) {
  return (ctx.*topic_qos<Sample>().topic)();
}

/// The QoS of Sample's writers (Q = DataWriterQos) or readers (DataReaderQos): the
/// profile <prefix>_writer or <prefix>_reader when the profiles are loaded (true),
/// else the built-in values (false). Needs the publisher or the subscriber.
template <class Sample, class Q>
bool endpoint_qos(DdsContext& ctx, Q& q) {
  constexpr bool writer = std::is_same_v<Q, fdds::DataWriterQos>;
  const TopicQos& t = topic_qos<Sample>();
  const std::string name = std::string(t.profile_prefix) + (writer ? "_writer" : "_reader");
  if constexpr (writer)
    ctx.publisher()->get_default_datawriter_qos(q);
  else
    ctx.subscriber()->get_default_datareader_qos(q);
  if (ctx.qos_from_profile(name, q)) return true;
  if constexpr (writer)
    t.writer_defaults(q);
  else
    t.reader_defaults(q);
  return false;
}

/// Stops the writer's or reader's callbacks (before its listener goes away) and
/// deletes it; nothing for null.
template <class Entity>
void delete_endpoint(DdsContext& ctx, Entity* e) {
  if (e == nullptr) return;
  e->set_listener(nullptr);
  if constexpr (std::is_same_v<Entity, fdds::DataWriter>)
    ctx.publisher()->delete_datawriter(e);
  else
    ctx.subscriber()->delete_datareader(e);
}

/// Takes every sample the reader holds; f(sample, info) for each valid one.
template <class Sample, class F>
void take_each(fdds::DataReader& reader, F&& f) {
  fdds::SampleInfo info;
  Sample sample;
  while (reader.take_next_sample(&sample, &info) == ReturnCode_t::RETCODE_OK)
    if (info.valid_data) f(sample, info);
}

/// A reader of Sample's topic without a listener yet (it is attached once the
/// listener knows the reader), without data sharing.
template <class Sample>
fdds::DataReader* create_reader(DdsContext& ctx, fdds::DataReaderQos& q) {
  no_data_sharing(q);
  return ctx.subscriber()->create_datareader(topic_of<Sample>(ctx), q, nullptr, fdds::StatusMask::none());
}

// The participant's transports when no profile is loaded (the same as
// "ve_participant" in deploy/dds-profiles.xml): UDPv4 only, no shared memory.
//
// Why no shared memory (docs/dds-integration.md has the whole story): Fast DDS
// 2.9's shared-memory transport lets a sender lock a mutex that lives in the
// RECEIVER's port segment (/dev/shm/fastrtps_port*: the port's empty_cv_mutex
// and its condition's list mutex) for every message it pushes. Those are
// process-shared pthread mutexes without the robust attribute (Boost.Interprocess
// 1.74, as Debian builds Fast DDS), locked with a 1 s timeout that throws. A
// sender SIGKILLed while it holds one leaves it locked for good; the receiver's
// listening thread then throws "Interprocess mutex timeout when locking. Possible
// deadlock: owner died without unlocking?" from listener_processing_stop(), which
// nothing catches on that thread: std::terminate, the receiver aborts (fixed
// upstream in Fast DDS 2.6.6, 2.10.2, 2.11.2 and 2.12, not in Debian's 2.9.1). A process that
// has no shared-memory transport never touches another process' segments: a
// killed encoder cannot take a consumer with it, whatever the consumer's own
// transports, and a killed consumer cannot take the encoder with it. It also
// announces no shared-memory port, so a restart is not held up by peers writing
// into the dead process' ports. Data sharing (another shared-memory path) is off
// on every endpoint as well (keyed types cannot use it in 2.9; stated anyway).
// Measured with tests/integration/publisher_kill_test.cpp (docs/dds-integration.md).
void udp_only(fdds::DomainParticipantQos& pq) {
  namespace rtps = eprosima::fastdds::rtps;
  pq.transport().use_builtin_transports = false;
  pq.transport().user_transports.clear();
  auto udp = std::make_shared<rtps::UDPv4TransportDescriptor>();
  udp->receiveBufferSize = transport::kUdpReceiveBufferBytes;
  pq.transport().user_transports.push_back(udp);
}

// Discovery after a restart (the same as ve_participant in deploy/dds-profiles.xml):
// a restarted encoder sometimes learns of a subscriber only from the subscriber's
// next periodic announcement, every 3 s by default, and sends it nothing until then
// (11-21 of 100 restarts reached Fast DDS subscribers 1-3 s after the exec). This
// participant announces itself every 0.5 s (the lease stays 20 s): a subscriber
// doing so received every one of 40 restarts within 0.6 s (publisher_kill_test,
// loaded host; docs/dds-integration.md). At its start it announces itself 20 times
// every 50 ms (Fast DDS: 5 every 100 ms).
void announce_often(fdds::DomainParticipantQos& pq) {
  auto& d = pq.wire_protocol().builtin.discovery_config;
  d.leaseDuration_announcementperiod = duration_ms(500.0);
  d.initial_announcements.count = 20;
  d.initial_announcements.period = duration_ms(50.0);
}

/// Fast DDS's own log (its default consumer prints to stdout, where `monitor --csv`
/// writes its rows) goes through the product's logger instead, to stderr like every
/// other log line: errors as errors, warnings as warnings, named "Fast DDS" with
/// Fast DDS's category. Installed once per process, before the first participant.
class FastDdsLogToSpdlog : public fdds::LogConsumer {
 public:
  explicit FastDdsLogToSpdlog(std::shared_ptr<spdlog::logger> logger) : logger_(std::move(logger)) {}
  void Consume(const fdds::Log::Entry& e) override {
    const auto level = e.kind == fdds::Log::Kind::Error     ? spdlog::level::err
                       : e.kind == fdds::Log::Kind::Warning ? spdlog::level::warn
                                                            : spdlog::level::debug;
    std::string message = e.message;
    while (!message.empty() && (message.back() == '\n' || message.back() == ' ')) message.pop_back();
    logger_->log(level, "Fast DDS [{}]: {}", e.context.category != nullptr ? e.context.category : "", message);
  }

 private:
  std::shared_ptr<spdlog::logger> logger_;  // kept alive for Fast DDS's log thread
};

void route_fastdds_log() {
  static std::once_flag once;
  std::call_once(once, [] {
    fdds::Log::ClearConsumers();
    fdds::Log::RegisterConsumer(std::make_unique<FastDdsLogToSpdlog>(spdlog::default_logger()));
    fdds::Log::SetVerbosity(fdds::Log::Kind::Warning);
  });
}

/// The kernel caps SO_RCVBUF at net.core.rmem_max without an error (Debian's
/// default is 212992 bytes): say so once, since the state stream then has only
/// that much room for a reader's scheduling hiccup (deploy/dds-profiles.xml, ve_udp).
void warn_if_receive_buffer_capped(const fdds::DomainParticipantQos& pq) {
  std::uint32_t asked = 0;
  for (const auto& t : pq.transport().user_transports)
    if (auto udp = std::dynamic_pointer_cast<eprosima::fastdds::rtps::UDPv4TransportDescriptor>(t))
      asked = std::max(asked, udp->receiveBufferSize);
  if (asked == 0) return;
  std::ifstream in("/proc/sys/net/core/rmem_max");
  unsigned long rmem_max = 0;
  if (!(in >> rmem_max) || rmem_max >= asked) return;
  static std::atomic<bool> warned{false};
  if (warned.exchange(true)) return;
  spdlog::warn("DDS: the UDP receive buffer asked for ({} KiB) is capped at net.core.rmem_max ({} KiB): less room "
               "for a reader's scheduling hiccup than configured, best-effort state samples beyond it are dropped by "
               "the kernel; set net.core.rmem_max >= {} (sysctl)",
               asked / 1024, rmem_max / 1024, asked);
}

}  // namespace

// ---------------------------------------------------------------- DdsContext

namespace {
bool env_flag(const char* name) {
  const char* v = std::getenv(name);
  return v != nullptr && (std::string(v) == "1" || std::string(v) == "true" || std::string(v) == "yes");
}
}  // namespace

bool DdsOptions::type_information_from_env() { return env_flag("VE_DDS_TYPE_INFORMATION"); }
bool DdsOptions::type_object_from_env() { return env_flag("VE_DDS_TYPE_OBJECT"); }

namespace {

/// Creates Fast DDS 2.9's type registries and fills them with the product's types, once per
/// process (see DdsContext::create, which calls it before its participant exists).
void prime_type_registries() {
  static std::once_flag primed;
  std::call_once(primed, [] {
    eprosima::fastrtps::types::TypeObjectFactory::get_instance();
    eprosima::fastrtps::types::DynamicTypeBuilderFactory::get_instance();
    eprosima::fastrtps::types::DynamicDataFactory::get_instance();
    registerVirtualEncoderTypes();
  });
}

}  // namespace

std::unique_ptr<DdsContext> DdsContext::create(const DdsOptions& options, std::string& error) {
  route_fastdds_log();  // before the factory, which may already parse a profiles file
  auto* factory = fdds::DomainParticipantFactory::get_instance();
  // FASTRTPS_DEFAULT_PROFILES_FILE / DEFAULT_FASTRTPS_PROFILES.xml, then the machine's file.
  factory->load_profiles();
  if (!options.profiles_file.empty() &&
      factory->load_XML_profiles_file(options.profiles_file) != ReturnCode_t::RETCODE_OK) {
    error = "cannot load DDS profiles file '" + options.profiles_file + "'";
    return nullptr;
  }
  // Fast DDS 2.9's type registries are filled here, on this thread, before any participant
  // (and so any receive thread) exists. A peer built with fastddsgen's defaults (a drive
  // controller, tests/tools/bare_reader.cpp) announces a complete TypeObject, and this
  // participant then builds a DynamicType from it on its receive threads
  // (PDP::check_and_notify_type_discovery). There, TypeObjectFactory,
  // DynamicTypeBuilderFactory and DynamicDataFactory are created lazily without a lock,
  // and the generated code fills the registry on the first construction of one of our
  // samples, with writes outside the registry's lock: either, concurrent with a receive
  // thread, crashed `run` (seen under AddressSanitizer: a SEGV in
  // DynamicType::get_all_members on a receive thread of a `run` restarted among such
  // readers). Afterwards every later registration finds its entries and stores nothing new.
  prime_type_registries();

  std::unique_ptr<DdsContext> ctx(new DdsContext());
  fdds::DomainParticipantQos pq;
  const char* env_profiles = std::getenv("FASTRTPS_DEFAULT_PROFILES_FILE");
  ctx->profiles_loaded_ = !options.profiles_file.empty() || (env_profiles != nullptr && *env_profiles != '\0');
  if (ctx->profiles_loaded_ &&
      factory->get_participant_qos_from_profile(options.participant_profile, pq) == ReturnCode_t::RETCODE_OK) {
    ctx->participant_from_profile_ = true;
  } else if (options.participant_profile != profile::kParticipant) {
    // A profile other than the default one was asked for by name: no silent fallback.
    error = "no DDS participant profile '" + options.participant_profile + "' loaded";
    return nullptr;
  } else {
    factory->get_default_participant_qos(pq);
    if (!options.receive_over_shm) {
      udp_only(pq);
      announce_often(pq);
    }
  }
  pq.name(options.participant_name);
  if (!options.statistics.empty()) {
    // The statistics module is compiled into Debian's Fast DDS; this property
    // turns on the named topics for this participant.
    std::string topics;
    for (const auto& t : options.statistics) topics += (topics.empty() ? "" : ";") + t;
    pq.properties().properties().emplace_back("fastdds.statistics", topics);
  }
  ctx->participant_ = factory->create_participant(static_cast<fdds::DomainId_t>(options.domain), pq);
  if (ctx->participant_ == nullptr) {
    error = "cannot create a DDS participant on domain " + std::to_string(options.domain);
    return nullptr;
  }
  warn_if_receive_buffer_capped(pq);
  fdds::TypeSupport state_type(new ve::dds::EncoderStatePubSubType());
  fdds::TypeSupport description_type(new ve::dds::AxisDescriptionPubSubType());
  fdds::TypeSupport diagnostics_type(new ve::dds::DiagnosticsPubSubType());
  fdds::TypeSupport command_type(new ve::dds::CalibrationCommandPubSubType());
  fdds::TypeSupport cal_status_type(new ve::dds::CalibrationStatusPubSubType());
  // TypeObject in discovery (PID_TYPE_OBJECT) only on request: a Fast DDS 2.9 receiver
  // builds a DynamicType from it on its receive threads, which is not thread-safe (see
  // DdsOptions::type_object). XTypes 1.3 TypeInformation (PID 0x75) only on request too:
  // Cyclone DDS 0.10 rejects Fast DDS 2.9's encoding of it and then ignores the endpoint.
  for (auto* t : {&state_type, &description_type, &diagnostics_type, &command_type, &cal_status_type}) {
    (*t)->auto_fill_type_object(options.type_object);
    (*t)->auto_fill_type_information(options.type_information);
    if (t->register_type(ctx->participant_) != ReturnCode_t::RETCODE_OK) {
      error = "cannot register the DDS type " + t->get_type_name();
      return nullptr;
    }
  }
  ctx->state_topic_ = ctx->participant_->create_topic(kStateTopic, state_type.get_type_name(), fdds::TOPIC_QOS_DEFAULT);
  ctx->description_topic_ =
      ctx->participant_->create_topic(kDescriptionTopic, description_type.get_type_name(), fdds::TOPIC_QOS_DEFAULT);
  ctx->diagnostics_topic_ =
      ctx->participant_->create_topic(kDiagnosticsTopic, diagnostics_type.get_type_name(), fdds::TOPIC_QOS_DEFAULT);
  ctx->calibration_command_topic_ =
      ctx->participant_->create_topic(kCalibrationCommandTopic, command_type.get_type_name(), fdds::TOPIC_QOS_DEFAULT);
  ctx->calibration_status_topic_ =
      ctx->participant_->create_topic(kCalibrationStatusTopic, cal_status_type.get_type_name(), fdds::TOPIC_QOS_DEFAULT);
  if (ctx->state_topic_ == nullptr || ctx->description_topic_ == nullptr || ctx->diagnostics_topic_ == nullptr ||
      ctx->calibration_command_topic_ == nullptr || ctx->calibration_status_topic_ == nullptr) {
    error = "cannot create the DDS topics";
    return nullptr;
  }
  return ctx;
}

template <class Q>
bool DdsContext::qos_from_profile(const std::string& name, Q& q) {
  constexpr bool writer = std::is_same_v<Q, fdds::DataWriterQos>;
  if (!profiles_loaded_ || (writer ? publisher() == nullptr : subscriber() == nullptr)) return false;
  Q from;
  ReturnCode_t found;
  if constexpr (writer)
    found = publisher_->get_datawriter_qos_from_profile(name, from);
  else
    found = subscriber_->get_datareader_qos_from_profile(name, from);
  if (found != ReturnCode_t::RETCODE_OK) return false;
  q = from;
  return true;
}

template bool DdsContext::qos_from_profile(const std::string&, fdds::DataWriterQos&);
template bool DdsContext::qos_from_profile(const std::string&, fdds::DataReaderQos&);

fdds::Publisher* DdsContext::publisher() {
  if (publisher_ == nullptr) publisher_ = participant_->create_publisher(fdds::PUBLISHER_QOS_DEFAULT);
  return publisher_;
}

fdds::Subscriber* DdsContext::subscriber() {
  if (subscriber_ == nullptr) subscriber_ = participant_->create_subscriber(fdds::SUBSCRIBER_QOS_DEFAULT);
  return subscriber_;
}

DdsContext::~DdsContext() {
  if (participant_ == nullptr) return;
  // Writers and readers are deleted by their owners first; this removes the rest.
  participant_->delete_contained_entities();
  fdds::DomainParticipantFactory::get_instance()->delete_participant(participant_);
  fdds::Log::Flush();  // Fast DDS logs from its own thread: out before the process goes on
}

// ---------------------------------------------------------------- StateWriter

struct StateWriter::Slot {
  fdds::DataWriter* writer = nullptr;  ///< its group's writer (shared lock and deadline timer), owned by writers_
  std::uint32_t axis_id = 0;
  std::string name;
  eprosima::fastrtps::rtps::InstanceHandle_t handle;
  DeadlineCounters counters;
  std::atomic<std::int64_t> last_write_ns{0};  ///< steady clock, set by the axis thread
  std::mutex periods_mutex;  ///< periods: at a report (listener thread) vs after a long gap (axis thread)
  DeadlinePeriods periods;
  std::mutex episode_mutex;           ///< start (listener thread) vs end (axis thread)
  std::uint64_t missed_at_start = 0;
  std::int64_t episode_start_ns = 0;
  std::atomic<bool> retired{false};  ///< set by the axis thread, read by the listener
};

class StateWriter::Listener : public fdds::DataWriterListener {
 public:
  explicit Listener(StateWriter& w) : writer(w) {}
  void on_offered_deadline_missed(fdds::DataWriter* w, const fdds::OfferedDeadlineMissedStatus& s) override {
    // One call per report of one instance; slots are fixed before publishing starts.
    if (writer.is_pacer(w, s.last_instance_handle)) {
      writer.pacer_reports_.fetch_add(1, std::memory_order_relaxed);
      return;
    }
    for (auto& slot : writer.slots_) {
      if (slot->writer != w || slot->handle != s.last_instance_handle) continue;
      // A retired axis' instance is gone, but a writer whose deadline timer was set for
      // it (a writer of that one axis) still fires once for it: not a miss.
      if (slot->retired.load()) return;
      const auto now = steady_ns();
      std::uint64_t added = 0;
      {
        std::lock_guard<std::mutex> lock(slot->periods_mutex);
        added = slot->periods.on_report(slot->last_write_ns.load(), now, writer.deadline_ns_);
      }
      if (added == 0)
        slot->counters.early_reports.fetch_add(1);
      else
        writer.count_missed(*slot, added, now);
      return;
    }
  }
  void on_publication_matched(fdds::DataWriter* w, const fdds::PublicationMatchedStatus& s) override {
    // Per group writer (a callback may come while a later group is being added).
    std::lock_guard<std::mutex> lock(matched_mutex);
    matched[w] = s.current_count;
  }
  int matched_max() {
    std::lock_guard<std::mutex> lock(matched_mutex);
    int n = 0;
    for (const auto& [w, count] : matched) n = std::max(n, count);
    return n;
  }
  StateWriter& writer;
  std::mutex matched_mutex;
  std::map<const fdds::DataWriter*, int> matched;
};

StateWriter::StateWriter(DdsContext& ctx, double deadline_ms) : ctx_(ctx), listener_(std::make_unique<Listener>(*this)) {
  auto* pub = ctx_.publisher();
  if (pub == nullptr) return;
  fdds::DataWriterQos q;
  from_profile_ = endpoint_qos<ve::dds::EncoderState>(ctx_, q);
  if (!from_profile_ && deadline_ms <= 0) q.deadline().period = eprosima::fastrtps::c_TimeInfinite;
  if (deadline_ms > 0) q.deadline().period = std::isinf(deadline_ms) ? eprosima::fastrtps::c_TimeInfinite
                                                                     : duration_ms(deadline_ms);
  no_data_sharing(q);
  // VE_DDS_STATE_NO_PACER=1 (measurements only, docs/dds-interface.md): no pacing instance,
  // so Fast DDS re-arms each writer's deadline timer once per tick, as before it existed.
  if (const char* no_pacer = std::getenv("VE_DDS_STATE_NO_PACER"); no_pacer != nullptr && std::string(no_pacer) == "1") {
    spdlog::warn("VE_DDS_STATE_NO_PACER=1: the state writers have no pacing instance (for measurements only)");
    pacing_ = false;
  }
  deadline_ms_ = to_ms(q.deadline().period);
  deadline_ns_ = static_cast<std::int64_t>(std::llround(deadline_ms_ * 1e6));
  qos_ = std::make_unique<fdds::DataWriterQos>(q);
  // No writer yet: each group of axes gets one in add_group(), and those are the only
  // state writers there are (an earlier writer made here that only ever matched
  // readers showed up in discovery as a second state writer that never wrote).
  // ok() still says whether a writer can be made from these QoS: Fast DDS
  // checks them on a writer created disabled, in a publisher of its own that does not
  // enable what it creates, so the probe never reaches discovery.
  fdds::PublisherQos probe_qos = fdds::PUBLISHER_QOS_DEFAULT;
  probe_qos.entity_factory().autoenable_created_entities = false;
  if (auto* probe_pub = ctx_.participant()->create_publisher(probe_qos)) {
    if (auto* probe = probe_pub->create_datawriter(ctx_.state_topic(), q, nullptr, fdds::StatusMask::none())) {
      ok_ = true;
      probe_pub->delete_datawriter(probe);
    }
    ctx_.participant()->delete_publisher(probe_pub);
  }
}

StateWriter::~StateWriter() {
  for (auto* w : writers_) delete_endpoint(ctx_, w);
}

std::vector<int> StateWriter::add_group(const std::vector<AxisName>& axes) {
  if (!ok_ || axes.empty()) return {};
  std::vector<std::unique_ptr<Slot>> added;
  ve::dds::EncoderStatePubSubType type;
  for (const auto& axis : axes) {
    auto slot = std::make_unique<Slot>();
    slot->axis_id = axis.axis_id;
    slot->name = axis.name;
    // The instance handle of a key <= 16 bytes is computed from the key alone; the
    // instance is not registered here, so no deadline runs before the first write.
    ve::dds::EncoderState key{};
    key.axis_id(axis.axis_id);
    type.getKey(&key, &slot->handle, false);
    added.push_back(std::move(slot));
  }
  // One writer for the group, one instance per axis: Fast DDS 2.9 keeps at most 10
  // instances per writer by default (max_instances), so the limits are raised to the
  // group's size. It also refuses max_samples below max_instances times
  // max_samples_per_instance (defaults 5000, 10 and 400: 16 axes would need 6400); a
  // keep-last history never holds more than its depth per instance, so that is the
  // per-instance limit, and max_samples is raised to hold it for every instance.
  fdds::DataWriterQos q = *qos_;
  auto& limits = q.resource_limits();
  // One instance more than the axes for the pacing instance (below), when a deadline is offered.
  const bool pacer = pacing_ && deadline_ns_ > 0;
  const auto n = static_cast<std::int32_t>(axes.size()) + (pacer ? 1 : 0);
  if (limits.max_instances > 0 && limits.max_instances < n) limits.max_instances = n;
  if (q.history().kind == fdds::KEEP_LAST_HISTORY_QOS && q.history().depth > 0 &&
      (limits.max_samples_per_instance <= 0 || limits.max_samples_per_instance > q.history().depth))
    limits.max_samples_per_instance = q.history().depth;
  if (limits.max_samples > 0 && limits.max_samples_per_instance > 0 &&
      limits.max_samples < limits.max_instances * limits.max_samples_per_instance)
    limits.max_samples = limits.max_instances * limits.max_samples_per_instance;
  // A stalled or bursting group never holds the lock another group writes through, so
  // the deadlines of axes in different sample threads stay independent in the process.
  auto* w = ctx_.publisher()->create_datawriter(
      ctx_.state_topic(), q, listener_.get(),
      fdds::StatusMask::offered_deadline_missed() << fdds::StatusMask::publication_matched());
  if (w == nullptr) return {};
  writers_.push_back(w);
  if (pacer) register_pacer(w, axes);
  std::vector<int> indices;
  for (auto& slot : added) {
    slot->writer = w;
    slots_.push_back(std::move(slot));
    indices.push_back(static_cast<int>(slots_.size() - 1));
  }
  return indices;
}

void StateWriter::register_pacer(fdds::DataWriter* w, const std::vector<AxisName>& axes) {
  // The pacing instance: registered and never written, so no reader ever hears of it.
  // Its key is one no axis of this writer has (readers never see it, so only this
  // writer's axes matter).
  std::uint32_t id = 0xFFFFFFFFu;
  while (std::any_of(axes.begin(), axes.end(), [&](const AxisName& a) { return a.axis_id == id; })) --id;
  ve::dds::EncoderState key{};
  key.axis_id(id);
  const auto handle = w->register_instance(&key);
  if (handle == eprosima::fastrtps::rtps::c_InstanceHandle_Unknown) {
    // Without it the writer re-arms its deadline timer as it did before (once per tick).
    spdlog::debug("state writer: the pacing instance could not be registered; the deadline timer is re-armed per tick");
    return;
  }
  std::lock_guard<std::mutex> lock(pacers_mutex_);
  pacers_.push_back({w, handle});
}

bool StateWriter::is_pacer(const fdds::DataWriter* w, const eprosima::fastrtps::rtps::InstanceHandle_t& h) const {
  std::lock_guard<std::mutex> lock(pacers_mutex_);
  for (const auto& p : pacers_)
    if (p.writer == w && p.handle == h) return true;
  return false;
}

int StateWriter::add_axis(std::uint32_t axis_id, const std::string& name) {
  const auto slots = add_group({AxisName{axis_id, name}});
  return slots.empty() ? -1 : slots.front();
}

const DeadlineCounters& StateWriter::counters(int slot) const { return slots_.at(static_cast<std::size_t>(slot))->counters; }

void StateWriter::poll_deadline_episode(int index, std::int64_t now_ns) {
  Slot& slot = *slots_[static_cast<std::size_t>(index)];
  if (!slot.counters.in_episode.load(std::memory_order_relaxed)) return;
  const std::int64_t quiet_ns = std::max<std::int64_t>(500000000, static_cast<std::int64_t>(10 * deadline_ms_ * 1e6));
  if (now_ns - slot.counters.last_miss_ns.load() < quiet_ns) return;
  std::lock_guard<std::mutex> lock(slot.episode_mutex);
  if (!slot.counters.in_episode.load()) return;
  slot.counters.in_episode.store(false);
  spdlog::info("axis '{}' (id {}): deadline episode {} over: {} miss(es) in {:.3f} s", slot.name, slot.axis_id,
               slot.counters.episodes.load(), slot.counters.missed.load() - slot.missed_at_start,
               (slot.counters.last_miss_ns.load() - slot.episode_start_ns) * 1e-9);
}

void StateWriter::retire_axis(int index) {
  Slot& slot = *slots_[static_cast<std::size_t>(index)];
  if (slot.retired.load() || slot.writer == nullptr) return;
  slot.retired.store(true);
  ve::dds::EncoderState key{};
  key.axis_id(slot.axis_id);
  // Disposed first, then unregistered. Fast DDS 2.9.1's writer waits for one instance's
  // deadline at a time (its "timer owner", the instance whose deadline comes first) and
  // moves on to the next only when that instance is written or misses. A best-effort
  // writer's unregister removes the instance from the history before the deadline is
  // looked at (DataWriterImpl::perform_create_new_change, set_next_deadline fails and Fast
  // DDS logs "Could not set the next deadline in the history"): had the instance been the
  // owner, the timer would fire for it once more and then stop for good, and the other
  // axes of the group would have no deadline any more. The dispose is a write of the
  // instance that keeps it: it moves its deadline last, so that another instance is the
  // owner when it goes. Readers see the instance disposed, as the unregister alone did
  // (autodispose_unregistered_instances, true by default).
  slot.writer->dispose(&key, slot.handle);
  slot.writer->unregister_instance(&key, slot.handle);
}

void StateWriter::count_missed(Slot& slot, std::uint64_t periods, std::int64_t now_ns) {
  const auto missed = slot.counters.missed.fetch_add(periods) + periods;
  slot.counters.last_miss_ns.store(now_ns);
  std::lock_guard<std::mutex> lock(slot.episode_mutex);
  if (slot.counters.in_episode.load()) return;
  slot.counters.in_episode.store(true);
  slot.counters.episodes.fetch_add(1);
  slot.missed_at_start = missed - periods;
  slot.episode_start_ns = now_ns;
  spdlog::warn("axis '{}' (id {}): offered deadline of {} ms missed: no sample published in time "
               "(episode {}; logged once until it is over)",
               slot.name, slot.axis_id, deadline_ms_, slot.counters.episodes.load());
}

void StateWriter::note_write(Slot& slot) {
  if (deadline_ns_ <= 0) return;  // no deadline offered: nothing to count
  const std::int64_t now = steady_ns();
  const std::int64_t last = slot.last_write_ns.load(std::memory_order_relaxed);
  if (last == 0 || now - last < deadline_ns_) {
    slot.last_write_ns.store(now, std::memory_order_relaxed);
    return;
  }
  // A gap of a whole period or more ends here. Fast DDS reports it only at the
  // truncated times its timer fires (app/deadline_periods.hpp), possibly not at all
  // for a gap shorter than two of them: the periods it did not report are counted now.
  std::uint64_t added = 0;
  {
    std::lock_guard<std::mutex> lock(slot.periods_mutex);
    added = slot.periods.on_report(last, now, deadline_ns_);
    slot.last_write_ns.store(now);
  }
  if (added > 0) count_missed(slot, added, now);
}

bool StateWriter::write(int slot, const ve::dds::EncoderState& sample) {
  Slot& s = *slots_[static_cast<std::size_t>(slot)];
  note_write(s);
  return s.writer->write(const_cast<ve::dds::EncoderState*>(&sample));
}

bool StateWriter::write(const ve::dds::EncoderState& sample) {
  for (std::size_t i = 0; i < slots_.size(); ++i)
    if (slots_[i]->axis_id == sample.axis_id()) return write(static_cast<int>(i), sample);
  return false;  // not an axis of this writer (add_axis)
}

std::uint64_t StateWriter::deadline_missed_total() const {
  std::uint64_t n = 0;
  for (const auto& slot : slots_) n += slot->counters.missed.load();
  return n;
}

std::uint64_t StateWriter::deadline_early_reports() const {
  std::uint64_t n = 0;
  for (const auto& slot : slots_) n += slot->counters.early_reports.load();
  return n;
}

std::uint64_t StateWriter::deadline_missed(std::uint32_t axis_id) const {
  for (const auto& slot : slots_)
    if (slot->axis_id == axis_id) return slot->counters.missed.load();
  return 0;
}

int StateWriter::matched_readers() const { return listener_->matched_max(); }

// ---------------------------------------------------------------- TopicWriter

template <class Sample>
class TopicWriter<Sample>::Listener : public fdds::DataWriterListener {
 public:
  void on_publication_matched(fdds::DataWriter*, const fdds::PublicationMatchedStatus& s) override {
    matched.store(s.current_count);
  }
  std::atomic<int> matched{0};
};

template <class Sample>
TopicWriter<Sample>::TopicWriter(DdsContext& ctx) : TopicEndpoint(ctx), listener_(std::make_unique<Listener>()) {
  auto* pub = ctx_.publisher();
  if (pub == nullptr) return;
  fdds::DataWriterQos q;
  from_profile_ = endpoint_qos<Sample>(ctx_, q);
  no_data_sharing(q);
  entity_ = pub->create_datawriter(topic_of<Sample>(ctx_), q, listener_.get(), fdds::StatusMask::publication_matched());
}

template <class Sample>
TopicWriter<Sample>::~TopicWriter() {
  delete_endpoint(ctx_, entity_);
}

template <class Sample>
bool TopicWriter<Sample>::write(const Sample& sample) {
  return entity_->write(const_cast<Sample*>(&sample));
}

template <class Sample>
int TopicWriter<Sample>::matched_readers() const {
  return listener_->matched.load();
}

template class TopicWriter<ve::dds::Diagnostics>;
template class TopicWriter<ve::dds::AxisDescription>;
template class TopicWriter<ve::dds::CalibrationStatus>;
template class TopicWriter<ve::dds::CalibrationCommand>;

// ---------------------------------------------------------------- TopicReader

template <class Sample>
class TopicReader<Sample>::Listener : public fdds::DataReaderListener {
 public:
  explicit Listener(Callback cb) : callback(std::move(cb)) {}
  void on_data_available(fdds::DataReader* reader) override {
    take_each<Sample>(*reader, [this](const Sample& sample, const fdds::SampleInfo&) {
      if (callback) callback(sample);
    });
  }
  void on_subscription_matched(fdds::DataReader*, const fdds::SubscriptionMatchedStatus& s) override {
    matched.on_callback(s.current_count);
  }
  Callback callback;
  MatchCount matched;
};

template <class Sample>
TopicReader<Sample>::TopicReader(DdsContext& ctx, Callback on_sample)
    : TopicEndpoint(ctx), listener_(std::make_unique<Listener>(std::move(on_sample))) {
  if (ctx_.subscriber() == nullptr) return;
  fdds::DataReaderQos q;
  from_profile_ = endpoint_qos<Sample>(ctx_, q);
  entity_ = create_reader<Sample>(ctx_, q);
  if (entity_ == nullptr) return;
  entity_->set_listener(listener_.get(), fdds::StatusMask::data_available() << fdds::StatusMask::subscription_matched());
  listener_->on_data_available(entity_);
  listener_->matched.sync(*entity_);
}

template <class Sample>
TopicReader<Sample>::~TopicReader() {
  delete_endpoint(ctx_, entity_);
}

template <class Sample>
int TopicReader<Sample>::matched_writers() const {
  return listener_->matched.load();
}

template class TopicReader<ve::dds::CalibrationCommand>;
template class TopicReader<ve::dds::CalibrationStatus>;

// ---------------------------------------------------------------- StateReader

class StateReader::Listener : public fdds::DataReaderListener {
 public:
  Listener(Callback cb, DiagnosticsCallback dcb) : callback(std::move(cb)), diagnostics_callback(std::move(dcb)) {}

  void on_data_available(fdds::DataReader* reader) override {
    if (reader == diagnostics_reader) {
      take_each<ve::dds::Diagnostics>(*reader, [this](const ve::dds::Diagnostics& diag, const fdds::SampleInfo&) {
        {
          std::lock_guard<std::mutex> lock(mutex);
          auto& a = axis(diag.axis_id());
          a.diagnostics = diag;
          ++a.diagnostics_received;
        }
        diagnostics_total.fetch_add(1);
        if (diagnostics_callback) diagnostics_callback(diag);
      });
      return;
    }
    if (reader == description_reader) {
      take_each<ve::dds::AxisDescription>(*reader, [this](const ve::dds::AxisDescription& d, const fdds::SampleInfo&) {
        std::lock_guard<std::mutex> lock(mutex);
        auto& a = axis(d.axis_id());
        a.description = d;
        a.have_description = true;
      });
      return;
    }
    take_each<ve::dds::EncoderState>(*reader, [this](const ve::dds::EncoderState& s, const fdds::SampleInfo& info) {
      const auto now = std::chrono::steady_clock::now();
      std::int64_t gap_ns = 0;
      std::uint64_t gap_periods = 0;
      {
        std::lock_guard<std::mutex> lock(mutex);
        auto& a = axis(s.axis_id());
        if (a.received > 0 && s.sequence_number() > a.last.sequence_number() + 1)
          a.sequence_gaps += s.sequence_number() - a.last.sequence_number() - 1;
        a.last = s;
        ++a.received;
        auto& instance = handles[info.instance_handle];
        instance.axis_id = s.axis_id();
        const std::int64_t now_ns =
            std::chrono::duration_cast<std::chrono::nanoseconds>(now.time_since_epoch()).count();
        if (deadline_ns > 0 && count_silence(instance, now_ns)) {
          // A gap of a whole period or more ends: the periods check_deadlines() has not
          // counted yet (it looks only every half period) count now.
          gap_ns = now_ns - instance.last_sample_ns;  // logged whoever counted its periods
          gap_periods = static_cast<std::uint64_t>(gap_ns / deadline_ns);
        }
        instance.last_sample_ns = now_ns;
        auto& times = arrivals[s.axis_id()];
        times.push_back(now);
        while (!times.empty() && now - times.front() > std::chrono::seconds(1)) times.pop_front();
      }
      total.fetch_add(1);
      if (gap_ns > 0) log_gap(s.axis_id(), gap_ns, gap_periods);
      if (callback) callback(s);
    });
  }

  // A gap of a deadline period or more, once it is over: when it began (local time of
  // day, to the microsecond, to line it up with other logs of the host), how long it
  // was and the periods it cost. Rare by nature, so logged each time.
  static void log_gap(std::uint32_t axis_id, std::int64_t gap_ns, std::uint64_t periods) {
    spdlog::warn("monitor: axis id {}: no sample for {:.1f} ms from {}: {} requested deadline period(s) missed",
                 axis_id, gap_ns * 1e-6, drivers::time_of_day_us(drivers::realtime_ns() - gap_ns), periods);
  }

  // The requested deadline, checked here rather than by Fast DDS: Fast DDS 2.9 re-arms a
  // reader's deadline timer on every sample it receives, a wake-up of its event thread per
  // sample (about a third of `monitor`'s CPU at 10,000 samples/s, docs/dds-interface.md).
  // This thread looks every half period: an instance silent for a whole period or more gets
  // the whole periods not counted yet (app/deadline_periods.hpp), as a report would.
  void check_deadlines() {
    const std::int64_t step_ns = std::max<std::int64_t>(deadline_ns / 2, 1000000);
    std::unique_lock<std::mutex> lock(mutex);
    while (!stop_checking) {
      checker_wake.wait_for(lock, std::chrono::nanoseconds(step_ns), [this] { return stop_checking; });
      if (stop_checking) break;
      const std::int64_t now_ns = steady_ns();
      for (auto& [handle, instance] : handles) count_silence(instance, now_ns);
    }
  }

  void start_checking() {
    if (deadline_ns > 0) checker = std::thread([this] { check_deadlines(); });
  }

  void stop_checker() {
    {
      std::lock_guard<std::mutex> lock(mutex);
      stop_checking = true;
    }
    checker_wake.notify_all();
    if (checker.joinable()) checker.join();
  }

  // Fast DDS's best-effort reader counts the writers' RTPS sequence numbers it never
  // received: state samples a writer handed to the network that did not reach this
  // reader (lost on the way or at this host's socket). A sequence gap of an axis with
  // none of these was never sent (the encoder's write failed).
  void on_sample_lost(fdds::DataReader* reader, const fdds::SampleLostStatus& st) override {
    if (reader == state_reader && st.total_count_change > 0)
      lost_total.fetch_add(static_cast<std::uint64_t>(st.total_count_change));
  }

  void on_subscription_matched(fdds::DataReader* reader, const fdds::SubscriptionMatchedStatus& st) override {
    if (reader == state_reader) matched.on_callback(st.current_count);
    if (reader == diagnostics_reader) diagnostics_matched.on_callback(st.current_count);
  }

  /// The statistics of an axis, from its first sample of any topic on. With the mutex held.
  AxisStats& axis(std::uint32_t id) {
    auto& a = axes[id];
    a.axis_id = id;
    return a;
  }

  Callback callback;
  DiagnosticsCallback diagnostics_callback;
  // Set before the readers exist, so a callback can compare against them.
  std::atomic<fdds::DataReader*> state_reader{nullptr}, description_reader{nullptr}, diagnostics_reader{nullptr};
  std::mutex mutex;
  std::map<std::uint32_t, AxisStats> axes;
  std::map<std::uint32_t, std::deque<std::chrono::steady_clock::time_point>> arrivals;
  struct Instance {
    std::uint32_t axis_id = 0;
    std::int64_t last_sample_ns = 0;  ///< steady clock, when it was taken
    DeadlinePeriods periods;
  };
  std::map<eprosima::fastrtps::rtps::InstanceHandle_t, Instance> handles;
  /// With the mutex held: whether `instance` has been silent a whole deadline period or
  /// more at now_ns; if so, the whole periods of that silence not counted yet are added to
  /// its axis' and the total count (app/deadline_periods.hpp).
  bool count_silence(Instance& instance, std::int64_t now_ns) {
    if (instance.last_sample_ns == 0 || now_ns - instance.last_sample_ns < deadline_ns) return false;
    const std::uint64_t added = instance.periods.on_report(instance.last_sample_ns, now_ns, deadline_ns);
    missed_total.fetch_add(added);
    axes[instance.axis_id].deadline_missed += added;
    return true;
  }
  std::int64_t deadline_ns = 0;  ///< requested; set before the readers exist
  std::thread checker;           ///< check_deadlines(), while deadline_ns > 0
  std::condition_variable checker_wake;
  bool stop_checking = false;    ///< with the mutex held
  std::atomic<std::uint64_t> missed_total{0};
  std::atomic<std::uint64_t> total{0};
  std::atomic<std::uint64_t> lost_total{0};
  std::atomic<std::uint64_t> diagnostics_total{0};
  MatchCount matched;
  MatchCount diagnostics_matched;
};

StateReader::StateReader(DdsContext& ctx, double deadline_ms, Callback on_sample, DiagnosticsCallback on_diagnostics)
    : ctx_(ctx), listener_(std::make_unique<Listener>(std::move(on_sample), std::move(on_diagnostics))) {
  auto* sub = ctx_.subscriber();
  if (sub == nullptr) return;
  fdds::StatusMask mask = fdds::StatusMask::data_available() << fdds::StatusMask::subscription_matched()
                          << fdds::StatusMask::sample_lost();
  // The readers are created without a listener and get it once the listener knows them.
  fdds::DataReaderQos sq;
  endpoint_qos<ve::dds::EncoderState>(ctx_, sq);
  // No deadline asked of Fast DDS: this reader checks it itself (Listener::check_deadlines).
  // So it also matches a writer that offers a longer deadline, or none, and judges its
  // stream against deadline_ms all the same.
  sq.deadline().period = eprosima::fastrtps::c_TimeInfinite;
  // Nor a liveliness lease: with a finite one, Fast DDS 2.9's reader asserts the writer's
  // liveliness on every sample it receives, and re-arms its liveliness timer each time
  // (LivelinessManager::assert_liveliness: its event thread woken twice per sample, the
  // same cost as the deadline's). This reader does not watch liveliness: an encoder that
  // goes away is seen by its silence (the deadline above) and by the match count.
  sq.liveliness().lease_duration = eprosima::fastrtps::c_TimeInfinite;
  listener_->deadline_ns = deadline_ms > 0 ? static_cast<std::int64_t>(std::llround(deadline_ms * 1e6)) : 0;
  fdds::DataReaderQos dq;
  endpoint_qos<ve::dds::AxisDescription>(ctx_, dq);
  fdds::DataReaderQos gq;
  endpoint_qos<ve::dds::Diagnostics>(ctx_, gq);

  state_reader_ = create_reader<ve::dds::EncoderState>(ctx_, sq);
  description_reader_ = create_reader<ve::dds::AxisDescription>(ctx_, dq);
  diagnostics_reader_ = create_reader<ve::dds::Diagnostics>(ctx_, gq);
  listener_->state_reader = state_reader_;
  listener_->description_reader = description_reader_;
  listener_->diagnostics_reader = diagnostics_reader_;
  for (auto* r : {state_reader_, description_reader_, diagnostics_reader_}) {
    if (r == nullptr) continue;
    r->set_listener(listener_.get(), mask);
    // Samples that arrived before the listener was attached (transient-local
    // description): deliver them now.
    listener_->on_data_available(r);
  }
  // Matches made before the listener was attached (a writer already on the domain).
  if (state_reader_ != nullptr) listener_->matched.sync(*state_reader_);
  if (diagnostics_reader_ != nullptr) listener_->diagnostics_matched.sync(*diagnostics_reader_);
  if (state_reader_ != nullptr) listener_->start_checking();
}

StateReader::~StateReader() {
  listener_->stop_checker();
  for (auto* r : {state_reader_, description_reader_, diagnostics_reader_}) delete_endpoint(ctx_, r);
}

std::vector<AxisStats> StateReader::snapshot() {
  const auto now = std::chrono::steady_clock::now();
  std::lock_guard<std::mutex> lock(listener_->mutex);
  std::vector<AxisStats> out;
  for (auto& [id, a] : listener_->axes) {
    auto& times = listener_->arrivals[id];
    while (!times.empty() && now - times.front() > std::chrono::seconds(1)) times.pop_front();
    a.rate_hz = static_cast<double>(times.size());
    out.push_back(a);
  }
  return out;
}

std::uint64_t StateReader::deadline_missed_total() const { return listener_->missed_total.load(); }
int StateReader::matched_writers() const { return listener_->matched.load(); }
int StateReader::matched_diagnostics_writers() const { return listener_->diagnostics_matched.load(); }
std::uint64_t StateReader::total_received() const { return listener_->total.load(); }
std::uint64_t StateReader::samples_lost() const { return listener_->lost_total.load(); }
std::uint64_t StateReader::diagnostics_received() const { return listener_->diagnostics_total.load(); }

// ---------------------------------------------------------------- calibration

CalibrationStatusReader::CalibrationStatusReader(DdsContext& ctx, Callback on_status)
    : on_status_(std::move(on_status)), reader_(ctx, [this](const ve::dds::CalibrationStatus& s) { keep(s); }) {}

void CalibrationStatusReader::keep(const ve::dds::CalibrationStatus& s) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    all_.push_back(s);
    last_[s.axis_id()] = s;
  }
  if (on_status_) on_status_(s);
}

std::vector<ve::dds::CalibrationStatus> CalibrationStatusReader::received() {
  std::lock_guard<std::mutex> lock(mutex_);
  return all_;
}

bool CalibrationStatusReader::last(std::uint32_t axis_id, ve::dds::CalibrationStatus& out) {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto it = last_.find(axis_id);
  if (it == last_.end()) return false;
  out = it->second;
  return true;
}

}  // namespace ve::app
