#include "dds_io.hpp"

#include <chrono>
#include <cmath>
#include <deque>

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

#include "VirtualEncoderPubSubTypes.h"
#include "VirtualEncoderTypeObject.h"

namespace fdds = eprosima::fastdds::dds;
using eprosima::fastrtps::types::ReturnCode_t;

namespace ve::app {

namespace {

eprosima::fastrtps::Duration_t duration_ms(double ms) {
  const auto total_ns = static_cast<std::int64_t>(std::llround(ms * 1e6));
  return eprosima::fastrtps::Duration_t(static_cast<std::int32_t>(total_ns / 1000000000),
                                        static_cast<std::uint32_t>(total_ns % 1000000000));
}

// The state stream: the newest sample is what a drive wants, a late retransmission
// is worth nothing, so best effort with a history of one.
fdds::DataWriterQos state_writer_qos(fdds::Publisher* pub, double deadline_ms) {
  fdds::DataWriterQos q;
  pub->get_default_datawriter_qos(q);
  q.reliability().kind = fdds::BEST_EFFORT_RELIABILITY_QOS;
  q.durability().kind = fdds::VOLATILE_DURABILITY_QOS;
  q.history().kind = fdds::KEEP_LAST_HISTORY_QOS;
  q.history().depth = 1;
  if (deadline_ms > 0) q.deadline().period = duration_ms(deadline_ms);
  return q;
}

fdds::DataReaderQos state_reader_qos(fdds::Subscriber* sub, double deadline_ms) {
  fdds::DataReaderQos q;
  sub->get_default_datareader_qos(q);
  q.reliability().kind = fdds::BEST_EFFORT_RELIABILITY_QOS;
  q.durability().kind = fdds::VOLATILE_DURABILITY_QOS;
  q.history().kind = fdds::KEEP_LAST_HISTORY_QOS;
  q.history().depth = 64;  // the listener drains it; a burst from several axes must fit
  if (deadline_ms > 0) q.deadline().period = duration_ms(deadline_ms);
  return q;
}

}  // namespace

// ---------------------------------------------------------------- DdsContext

std::unique_ptr<DdsContext> DdsContext::create(const DdsOptions& options, std::string& error) {
  auto* factory = fdds::DomainParticipantFactory::get_instance();
  if (!options.profiles_file.empty() &&
      factory->load_XML_profiles_file(options.profiles_file) != ReturnCode_t::RETCODE_OK) {
    error = "cannot load DDS profiles file '" + options.profiles_file + "'";
    return nullptr;
  }
  // Type information for generic DDS tools (TypeObject / TypeLookup).
  registerVirtualEncoderTypes();

  std::unique_ptr<DdsContext> ctx(new DdsContext());
  fdds::DomainParticipantQos pq;
  factory->get_default_participant_qos(pq);
  pq.name(options.participant_name);
  ctx->participant_ = factory->create_participant(static_cast<fdds::DomainId_t>(options.domain), pq);
  if (ctx->participant_ == nullptr) {
    error = "cannot create a DDS participant on domain " + std::to_string(options.domain);
    return nullptr;
  }
  fdds::TypeSupport state_type(new ve::dds::EncoderStatePubSubType());
  fdds::TypeSupport description_type(new ve::dds::AxisDescriptionPubSubType());
  state_type->auto_fill_type_object(true);
  state_type->auto_fill_type_information(true);
  description_type->auto_fill_type_object(true);
  description_type->auto_fill_type_information(true);
  if (state_type.register_type(ctx->participant_) != ReturnCode_t::RETCODE_OK ||
      description_type.register_type(ctx->participant_) != ReturnCode_t::RETCODE_OK) {
    error = "cannot register the DDS types";
    return nullptr;
  }
  ctx->state_topic_ = ctx->participant_->create_topic(kStateTopic, state_type.get_type_name(), fdds::TOPIC_QOS_DEFAULT);
  ctx->description_topic_ =
      ctx->participant_->create_topic(kDescriptionTopic, description_type.get_type_name(), fdds::TOPIC_QOS_DEFAULT);
  if (ctx->state_topic_ == nullptr || ctx->description_topic_ == nullptr) {
    error = "cannot create the DDS topics";
    return nullptr;
  }
  return ctx;
}

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
}

// ---------------------------------------------------------------- StateWriter

class StateWriter::Listener : public fdds::DataWriterListener {
 public:
  void on_offered_deadline_missed(fdds::DataWriter*, const fdds::OfferedDeadlineMissedStatus& s) override {
    total.store(static_cast<std::uint64_t>(s.total_count));
    std::lock_guard<std::mutex> lock(mutex);
    ++per_instance[s.last_instance_handle];
  }
  void on_publication_matched(fdds::DataWriter*, const fdds::PublicationMatchedStatus& s) override {
    matched.store(s.current_count);
  }
  std::atomic<std::uint64_t> total{0};
  std::atomic<int> matched{0};
  std::mutex mutex;
  std::map<eprosima::fastrtps::rtps::InstanceHandle_t, std::uint64_t> per_instance;
};

StateWriter::StateWriter(DdsContext& ctx, double deadline_ms) : ctx_(ctx), listener_(std::make_unique<Listener>()) {
  auto* pub = ctx_.publisher();
  if (pub == nullptr) return;
  fdds::StatusMask mask = fdds::StatusMask::offered_deadline_missed() << fdds::StatusMask::publication_matched();
  writer_ = pub->create_datawriter(ctx_.state_topic(), state_writer_qos(pub, deadline_ms), listener_.get(), mask);
}

StateWriter::~StateWriter() {
  if (writer_ != nullptr) ctx_.publisher()->delete_datawriter(writer_);
}

bool StateWriter::write(const ve::dds::EncoderState& sample) {
  return writer_->write(const_cast<ve::dds::EncoderState*>(&sample));
}

std::uint64_t StateWriter::deadline_missed_total() const { return listener_->total.load(); }

std::uint64_t StateWriter::deadline_missed(std::uint32_t axis_id) const {
  ve::dds::EncoderState key{};
  key.axis_id(axis_id);
  const auto handle = writer_->lookup_instance(&key);
  std::lock_guard<std::mutex> lock(listener_->mutex);
  const auto it = listener_->per_instance.find(handle);
  return it == listener_->per_instance.end() ? 0 : it->second;
}

int StateWriter::matched_readers() const { return listener_->matched.load(); }

// ---------------------------------------------------------------- DescriptionWriter

DescriptionWriter::DescriptionWriter(DdsContext& ctx) : ctx_(ctx) {
  auto* pub = ctx_.publisher();
  if (pub == nullptr) return;
  fdds::DataWriterQos q;
  pub->get_default_datawriter_qos(q);
  // Late joiners must learn what each axis is: reliable, transient-local, last value per axis.
  q.reliability().kind = fdds::RELIABLE_RELIABILITY_QOS;
  q.durability().kind = fdds::TRANSIENT_LOCAL_DURABILITY_QOS;
  q.history().kind = fdds::KEEP_LAST_HISTORY_QOS;
  q.history().depth = 1;
  writer_ = pub->create_datawriter(ctx_.description_topic(), q);
}

DescriptionWriter::~DescriptionWriter() {
  if (writer_ != nullptr) ctx_.publisher()->delete_datawriter(writer_);
}

bool DescriptionWriter::write(const ve::dds::AxisDescription& d) {
  return writer_->write(const_cast<ve::dds::AxisDescription*>(&d));
}

// ---------------------------------------------------------------- StateReader

class StateReader::Listener : public fdds::DataReaderListener {
 public:
  explicit Listener(Callback cb) : callback(std::move(cb)) {}

  void on_data_available(fdds::DataReader* reader) override {
    fdds::SampleInfo info;
    if (reader->get_topicdescription()->get_name() == kDescriptionTopic) {
      ve::dds::AxisDescription d;
      while (reader->take_next_sample(&d, &info) == ReturnCode_t::RETCODE_OK) {
        if (!info.valid_data) continue;
        std::lock_guard<std::mutex> lock(mutex);
        auto& a = axes[d.axis_id()];
        a.axis_id = d.axis_id();
        a.description = d;
        a.have_description = true;
      }
      return;
    }
    ve::dds::EncoderState s;
    while (reader->take_next_sample(&s, &info) == ReturnCode_t::RETCODE_OK) {
      if (!info.valid_data) continue;
      const auto now = std::chrono::steady_clock::now();
      {
        std::lock_guard<std::mutex> lock(mutex);
        auto& a = axes[s.axis_id()];
        a.axis_id = s.axis_id();
        if (a.received > 0 && s.sequence_number() > a.last.sequence_number() + 1)
          a.sequence_gaps += s.sequence_number() - a.last.sequence_number() - 1;
        a.last = s;
        ++a.received;
        handles[info.instance_handle] = s.axis_id();
        auto& times = arrivals[s.axis_id()];
        times.push_back(now);
        while (!times.empty() && now - times.front() > std::chrono::seconds(1)) times.pop_front();
      }
      total.fetch_add(1);
      if (callback) callback(s);
    }
  }

  void on_requested_deadline_missed(fdds::DataReader*, const fdds::RequestedDeadlineMissedStatus& st) override {
    missed_total.store(static_cast<std::uint64_t>(st.total_count));
    std::lock_guard<std::mutex> lock(mutex);
    const auto it = handles.find(st.last_instance_handle);
    if (it != handles.end()) ++axes[it->second].deadline_missed;
  }

  void on_subscription_matched(fdds::DataReader* reader, const fdds::SubscriptionMatchedStatus& st) override {
    if (reader->get_topicdescription()->get_name() == kStateTopic) matched.store(st.current_count);
  }

  Callback callback;
  std::mutex mutex;
  std::map<std::uint32_t, AxisStats> axes;
  std::map<std::uint32_t, std::deque<std::chrono::steady_clock::time_point>> arrivals;
  std::map<eprosima::fastrtps::rtps::InstanceHandle_t, std::uint32_t> handles;
  std::atomic<std::uint64_t> missed_total{0};
  std::atomic<std::uint64_t> total{0};
  std::atomic<int> matched{0};
};

StateReader::StateReader(DdsContext& ctx, double deadline_ms, Callback on_sample)
    : ctx_(ctx), listener_(std::make_unique<Listener>(std::move(on_sample))) {
  auto* sub = ctx_.subscriber();
  if (sub == nullptr) return;
  fdds::StatusMask mask = fdds::StatusMask::data_available() << fdds::StatusMask::requested_deadline_missed()
                          << fdds::StatusMask::subscription_matched();
  state_reader_ = sub->create_datareader(ctx_.state_topic(), state_reader_qos(sub, deadline_ms), listener_.get(), mask);
  fdds::DataReaderQos dq;
  sub->get_default_datareader_qos(dq);
  dq.reliability().kind = fdds::RELIABLE_RELIABILITY_QOS;
  dq.durability().kind = fdds::TRANSIENT_LOCAL_DURABILITY_QOS;
  dq.history().kind = fdds::KEEP_LAST_HISTORY_QOS;
  dq.history().depth = 1;
  description_reader_ = sub->create_datareader(ctx_.description_topic(), dq, listener_.get(), mask);
}

StateReader::~StateReader() {
  // Stop callbacks before the listener goes away.
  if (state_reader_ != nullptr) {
    state_reader_->set_listener(nullptr);
    ctx_.subscriber()->delete_datareader(state_reader_);
  }
  if (description_reader_ != nullptr) {
    description_reader_->set_listener(nullptr);
    ctx_.subscriber()->delete_datareader(description_reader_);
  }
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
std::uint64_t StateReader::total_received() const { return listener_->total.load(); }

}  // namespace ve::app
