// DDS side of the product: one participant per process, the encoder-state and
// axis-description topics, their writers (run) and readers (monitor, tests).
// Everything Fast DDS is behind this header so that the rest of the app deals in
// plain structs.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "VirtualEncoder.h"

namespace eprosima::fastdds::dds {
class DomainParticipant;
class Publisher;
class Subscriber;
class Topic;
class DataWriter;
class DataReader;
}  // namespace eprosima::fastdds::dds

namespace ve::app {

inline constexpr const char* kStateTopic = "ve/encoder_state";
inline constexpr const char* kDescriptionTopic = "ve/axis_description";

struct DdsOptions {
  int domain = 0;
  std::string profiles_file;       ///< Fast DDS XML profiles, loaded before the participant
  std::string participant_name = "virtual-encoder";
};

/// Owns the participant and the topics. Deleting it deletes every entity it
/// made, in order; keep it out of static storage.
class DdsContext {
 public:
  /// Returns nullptr and sets `error` when the participant cannot be created.
  static std::unique_ptr<DdsContext> create(const DdsOptions& options, std::string& error);
  ~DdsContext();
  DdsContext(const DdsContext&) = delete;
  DdsContext& operator=(const DdsContext&) = delete;

  eprosima::fastdds::dds::DomainParticipant* participant() const { return participant_; }
  eprosima::fastdds::dds::Topic* state_topic() const { return state_topic_; }
  eprosima::fastdds::dds::Topic* description_topic() const { return description_topic_; }
  eprosima::fastdds::dds::Publisher* publisher();
  eprosima::fastdds::dds::Subscriber* subscriber();

 private:
  DdsContext() = default;
  eprosima::fastdds::dds::DomainParticipant* participant_ = nullptr;
  eprosima::fastdds::dds::Topic* state_topic_ = nullptr;
  eprosima::fastdds::dds::Topic* description_topic_ = nullptr;
  eprosima::fastdds::dds::Publisher* publisher_ = nullptr;
  eprosima::fastdds::dds::Subscriber* subscriber_ = nullptr;
};

/// Writer of ve/encoder_state for all axes of this process (one instance per axis).
class StateWriter {
 public:
  StateWriter(DdsContext& ctx, double deadline_ms);
  ~StateWriter();
  bool ok() const { return writer_ != nullptr; }
  /// Thread-safe: Fast DDS serialises writes per writer.
  bool write(const ve::dds::EncoderState& sample);
  std::uint64_t deadline_missed_total() const;
  /// Offered deadline misses of one axis instance.
  std::uint64_t deadline_missed(std::uint32_t axis_id) const;
  int matched_readers() const;

 private:
  class Listener;
  DdsContext& ctx_;
  std::unique_ptr<Listener> listener_;
  eprosima::fastdds::dds::DataWriter* writer_ = nullptr;
};

/// Writer of ve/axis_description (reliable, transient-local).
class DescriptionWriter {
 public:
  explicit DescriptionWriter(DdsContext& ctx);
  ~DescriptionWriter();
  bool ok() const { return writer_ != nullptr; }
  bool write(const ve::dds::AxisDescription& d);

 private:
  DdsContext& ctx_;
  eprosima::fastdds::dds::DataWriter* writer_ = nullptr;
};

/// Per-axis statistics a subscriber keeps.
struct AxisStats {
  std::uint32_t axis_id = 0;
  ve::dds::EncoderState last{};
  std::uint64_t received = 0;
  std::uint64_t sequence_gaps = 0;      ///< samples missing according to sequence numbers
  std::uint64_t deadline_missed = 0;    ///< requested-deadline misses of this instance
  double rate_hz = 0.0;                 ///< measured over the last second
  bool have_description = false;
  ve::dds::AxisDescription description{};
};

/// Reader of both topics with per-axis statistics; optional callback per sample
/// (called on the Fast DDS listener thread).
class StateReader {
 public:
  using Callback = std::function<void(const ve::dds::EncoderState&)>;
  /// deadline_ms <= 0: no requested deadline.
  StateReader(DdsContext& ctx, double deadline_ms, Callback on_sample = {});
  ~StateReader();
  bool ok() const { return state_reader_ != nullptr && description_reader_ != nullptr; }

  std::vector<AxisStats> snapshot();
  std::uint64_t deadline_missed_total() const;
  int matched_writers() const;
  std::uint64_t total_received() const;

 private:
  class Listener;
  friend class Listener;
  DdsContext& ctx_;
  std::unique_ptr<Listener> listener_;
  eprosima::fastdds::dds::DataReader* state_reader_ = nullptr;
  eprosima::fastdds::dds::DataReader* description_reader_ = nullptr;
};

}  // namespace ve::app
