// DDS side of the product: one participant per process, the encoder-state,
// axis-description and diagnostics topics, their writers (run) and readers
// (monitor, tests). QoS come from the XML profiles (deploy/dds-profiles.xml) when
// they are loaded, else from identical built-in values. Everything Fast DDS is
// behind this header so that the rest of the app deals in plain structs.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include <fastdds/rtps/common/InstanceHandle.h>

#include "VirtualEncoder.h"

namespace eprosima::fastdds::dds {
class DomainParticipant;
class Publisher;
class Subscriber;
class Topic;
class DataWriter;
class DataReader;
class DataWriterQos;
class DataReaderQos;
}  // namespace eprosima::fastdds::dds

namespace ve::app {

inline constexpr const char* kStateTopic = "ve/encoder_state";
inline constexpr const char* kDescriptionTopic = "ve/axis_description";
inline constexpr const char* kDiagnosticsTopic = "ve/diagnostics";
inline constexpr const char* kCalibrationCommandTopic = "ve/calibration_command";
inline constexpr const char* kCalibrationStatusTopic = "ve/calibration_status";

/// Participant profile names in deploy/dds-profiles.xml. A topic's writers and
/// readers take the profiles <prefix>_writer and <prefix>_reader (ve_state_writer
/// and ve_state_reader for ve/encoder_state; the prefixes are in the table of
/// topics in dds_io.cpp).
namespace profile {
inline constexpr const char* kParticipant = "ve_participant";
/// Shared memory only: not in the shipped profiles (a killed shared-memory peer can
/// abort a Fast DDS 2.9 process: docs/dds-integration.md); measurements define it.
inline constexpr const char* kParticipantShm = "ve_participant_shm";
/// UDPv4 only, the same as kParticipant.
inline constexpr const char* kParticipantUdp = "ve_participant_udp";
}  // namespace profile

/// Buffer sizes of the product's transport (built-in QoS; the same values as the
/// ve_udp descriptor and ve_state_reader in deploy/dds-profiles.xml). Sized so that
/// a reader descheduled for tens of ms loses nothing of the state stream (3 axes x
/// 4 kHz = 12,000 datagrams/s on one socket, about 1.3 KiB of kernel buffer each):
/// see docs/dds-interface.md. The product has no shared-memory transport
/// (crash isolation: component/app/dds_io.cpp, udp_only(); docs/dds-integration.md).
namespace transport {
/// SO_RCVBUF asked for (the kernel doubles it, capped at net.core.rmem_max): with
/// 4 MiB about 6,500 datagrams, 0.5 s of the 3-axis stream; the Linux default of
/// 208 KiB held 166, 14 ms (bench_soak).
inline constexpr std::uint32_t kUdpReceiveBufferBytes = 4u * 1024u * 1024u;
/// ve_state_reader's history depth per axis instance (64 ms at 4 kHz).
inline constexpr std::int32_t kStateReaderDepth = 256;
/// Axes (instances) one reader keeps, per-axis topics: Fast DDS 2.9's default of 10
/// would drop the 11th axis of a machine, silently. The history grows as axes appear
/// (kReaderAllocatedAxes of them reserved at start), up to this many.
inline constexpr std::int32_t kReaderMaxAxes = 1024;
inline constexpr std::int32_t kReaderAllocatedAxes = 16;
}  // namespace transport

struct DdsOptions {
  int domain = 0;
  /// Fast DDS XML profiles, loaded before the participant. Profiles are also
  /// found in FASTRTPS_DEFAULT_PROFILES_FILE (Fast DDS loads it by itself).
  std::string profiles_file;
  /// Fast DDS statistics topics to enable (names as in fastdds/statistics/topic_names.hpp).
  std::vector<std::string> statistics;
  std::string participant_name = "virtual-encoder";
  /// Participant profile to use when profiles are loaded (else built-in QoS).
  std::string participant_profile = profile::kParticipant;
  /// Announce XTypes TypeInformation (for TypeLookup-based tools). Off by default:
  /// Cyclone DDS 0.10 rejects Fast DDS 2.9's TypeInformation and then ignores our
  /// endpoints. Default from the environment: VE_DDS_TYPE_INFORMATION=1 turns it on.
  bool type_information = type_information_from_env();
  static bool type_information_from_env();
  /// Announce the types' complete TypeObjects in discovery (for generic tools that
  /// build a type from it). Off by default: every Fast DDS 2.9 participant that
  /// discovers an endpoint carrying one builds a DynamicType from it on its receive
  /// threads, in type registries that are not thread-safe (created lazily without a
  /// lock; add_type_identifier writes its maps without the lock others read them
  /// under). A receiver whose registries are not filled before its participant exists
  /// can crash (seen: a SEGV in TypeObjectFactory::get_key_from_hash under
  /// AddressSanitizer); ours are (prime_type_registries), a drive controller's may not
  /// be. Default from the environment: VE_DDS_TYPE_OBJECT=1 turns it on.
  bool type_object = type_object_from_env();
  static bool type_object_from_env();
  /// Built-in QoS only (no participant profile): Fast DDS's default transports
  /// (shared memory and UDPv4) instead of the product's UDPv4 only. Off by
  /// default: the product never uses shared memory (crash isolation, see
  /// udp_only() in dds_io.cpp). Meant for test and bench subscribers standing in
  /// for a consumer with Fast DDS's defaults.
  bool receive_over_shm = false;
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
  eprosima::fastdds::dds::Topic* diagnostics_topic() const { return diagnostics_topic_; }
  eprosima::fastdds::dds::Topic* calibration_command_topic() const { return calibration_command_topic_; }
  eprosima::fastdds::dds::Topic* calibration_status_topic() const { return calibration_status_topic_; }
  eprosima::fastdds::dds::Publisher* publisher();
  eprosima::fastdds::dds::Subscriber* subscriber();

  /// The participant was made from the "ve_participant" profile (else built-in QoS).
  bool participant_from_profile() const { return participant_from_profile_; }
  /// Fill `q` (a DataWriterQos or a DataReaderQos) from a named profile; false (q
  /// untouched) when no such profile is loaded.
  template <class Q>
  bool qos_from_profile(const std::string& name, Q& q);

 private:
  DdsContext() = default;
  eprosima::fastdds::dds::DomainParticipant* participant_ = nullptr;
  eprosima::fastdds::dds::Topic* state_topic_ = nullptr;
  eprosima::fastdds::dds::Topic* description_topic_ = nullptr;
  eprosima::fastdds::dds::Topic* diagnostics_topic_ = nullptr;
  eprosima::fastdds::dds::Topic* calibration_command_topic_ = nullptr;
  eprosima::fastdds::dds::Topic* calibration_status_topic_ = nullptr;
  bool participant_from_profile_ = false;
  bool profiles_loaded_ = false;
  eprosima::fastdds::dds::Publisher* publisher_ = nullptr;
  eprosima::fastdds::dds::Subscriber* subscriber_ = nullptr;
};

/// Offered-deadline bookkeeping of one axis instance (see StateWriter::add_axis).
struct DeadlineCounters {
  std::atomic<std::uint64_t> missed{0};     ///< offered deadline periods missed by this instance
  /// Fast DDS reports that added no whole period without a sample (its timers run in
  /// whole milliseconds; app/deadline_periods.hpp): not misses.
  std::atomic<std::uint64_t> early_reports{0};
  std::atomic<std::uint64_t> episodes{0};   ///< runs of misses without a quiet time in between
  std::atomic<bool> in_episode{false};
  std::atomic<std::int64_t> last_miss_ns{0};  ///< steady clock
};

/// Writer of ve/encoder_state for all axes of this process (one instance per axis).
/// The axes are added in groups (add_group): the axes of one group share one keyed
/// DataWriter, one instance each; a group of one has a writer of its own. `run` makes
/// one group per sample thread (the axes one thread steps in turn; one group per axis
/// with dds.state_writer: per_axis), so a reader matches one state writer per sample
/// thread. Why a group shares a writer: Fast DDS 2.9 re-arms a writer's offered-deadline
/// timer (waking the participant's event thread) at every write of the instance whose
/// deadline comes first, so N writers of one instance each re-arm N times per tick, one
/// keyed writer written in alternating order (GroupWriteOrder) once; and each writer's
/// pacing instance (set_pacing), whose deadline comes first, brings that down to about
/// once per deadline period (docs/dds-interface.md, "What an offered deadline costs").
class StateWriter {
 public:
  /// deadline_ms > 0 replaces the profile's offered deadline; <= 0 keeps the profile's
  /// (or, without profiles, offers none); infinity offers none (for measurements only:
  /// a reader that requests a deadline does not match such a writer).
  StateWriter(DdsContext& ctx, double deadline_ms);
  ~StateWriter();
  /// The QoS are consistent (a writer can be made from them) and there is a publisher.
  bool ok() const { return ok_; }
  bool from_profile() const { return from_profile_; }
  double deadline_ms() const { return deadline_ms_; }

  struct AxisName {
    std::uint32_t axis_id = 0;
    std::string name;
  };
  /// Before publishing starts (not thread-safe): axes this writer publishes, written
  /// by one thread. They get one DataWriter on the topic (same QoS, its resource limits
  /// raised to hold one instance per axis), the only state writer of these axes.
  /// Each axis' deadline misses are counted per instance and logged once per episode
  /// (warn at the first miss, info when it is over). Returns the axes' slots in the
  /// given order; empty on failure (nothing added).
  std::vector<int> add_group(const std::vector<AxisName>& axes);
  /// A group of one: the axis has a DataWriter of its own. Returns its slot, -1 on failure.
  int add_axis(std::uint32_t axis_id, const std::string& name);
  const DeadlineCounters& counters(int slot) const;
  /// From the axis thread, now and then: ends (and logs) a miss episode after a
  /// quiet time of max(0.5 s, 10 deadlines). Cheap when nothing happened.
  void poll_deadline_episode(int slot, std::int64_t steady_now_ns);
  /// The axis stopped publishing: dispose and unregister its instance (no more deadline
  /// misses of it; the deadline of the other axes of its writer goes on).
  void retire_axis(int slot);

  /// The axis' sample thread's write, through its group's writer.
  bool write(int slot, const ve::dds::EncoderState& sample);
  /// Thread-safe: Fast DDS serialises writes per writer. Finds the axis' writer;
  /// false for an axis that was not added.
  bool write(const ve::dds::EncoderState& sample);
  /// Offered deadline periods missed by the added axes: whole periods without a write,
  /// counted when Fast DDS reports a miss (its early reports are counted apart).
  std::uint64_t deadline_missed_total() const;
  std::uint64_t deadline_early_reports() const;
  /// Offered deadline misses of one axis instance.
  std::uint64_t deadline_missed(std::uint32_t axis_id) const;
  /// Readers matched with the groups' writers (the most any one of them has).
  int matched_readers() const;
  /// Before add_group: whether each writer gets a pacing instance (on by default; off for
  /// measurements only). Fast DDS 2.9 re-arms a writer's deadline timer at a write of the
  /// instance whose deadline comes first; an instance registered and never written is
  /// that instance, so the timer is re-armed about once per period instead of once per
  /// tick, and fires for it every period, which is not counted as a miss
  /// (docs/dds-interface.md, "What an offered deadline costs"). The environment variable
  /// VE_DDS_STATE_NO_PACER=1 turns it off for a whole process (measurements only).
  void set_pacing(bool on) { pacing_ = on; }
  /// Fast DDS's deadline reports of the pacing instances (not misses of any axis).
  std::uint64_t pacer_reports() const { return pacer_reports_.load(); }

 private:
  class Listener;
  friend class Listener;
  struct Slot;
  struct Pacer {
    const eprosima::fastdds::dds::DataWriter* writer = nullptr;
    eprosima::fastrtps::rtps::InstanceHandle_t handle;
  };
  void register_pacer(eprosima::fastdds::dds::DataWriter* w, const std::vector<AxisName>& axes);
  bool is_pacer(const eprosima::fastdds::dds::DataWriter* w, const eprosima::fastrtps::rtps::InstanceHandle_t& h) const;
  bool pacing_ = true;
  mutable std::mutex pacers_mutex_;
  std::vector<Pacer> pacers_;
  std::atomic<std::uint64_t> pacer_reports_{0};
  void note_write(Slot& slot);
  void count_missed(Slot& slot, std::uint64_t periods, std::int64_t now_ns);
  DdsContext& ctx_;
  std::unique_ptr<Listener> listener_;
  std::vector<std::unique_ptr<Slot>> slots_;
  std::vector<eprosima::fastdds::dds::DataWriter*> writers_;  ///< one per group
  std::unique_ptr<eprosima::fastdds::dds::DataWriterQos> qos_;
  bool ok_ = false;
  bool from_profile_ = false;
  double deadline_ms_ = 0.0;
  std::int64_t deadline_ns_ = 0;
};

/// What the writer and the reader of one topic share: the Fast DDS entity (null
/// when it could not be made) and whether its QoS came from a profile.
template <class Entity>
class TopicEndpoint {
 public:
  TopicEndpoint(const TopicEndpoint&) = delete;
  TopicEndpoint& operator=(const TopicEndpoint&) = delete;
  bool ok() const { return entity_ != nullptr; }
  bool from_profile() const { return from_profile_; }

 protected:
  explicit TopicEndpoint(DdsContext& ctx) : ctx_(ctx) {}
  ~TopicEndpoint() = default;
  DdsContext& ctx_;
  Entity* entity_ = nullptr;
  bool from_profile_ = false;
};

/// The writer of one topic (Sample: its IDL type): QoS from the topic's writer
/// profile in deploy/dds-profiles.xml when the profiles are loaded, else the
/// identical built-in values; counts the readers matched. write() is thread-safe
/// (Fast DDS serialises writes per writer).
template <class Sample>
class TopicWriter : public TopicEndpoint<eprosima::fastdds::dds::DataWriter> {
 public:
  explicit TopicWriter(DdsContext& ctx);
  ~TopicWriter();
  bool write(const Sample& sample);
  int matched_readers() const;

 private:
  class Listener;
  std::unique_ptr<Listener> listener_;
};

/// The reader of one topic: QoS from the topic's reader profile when the profiles
/// are loaded, else the built-in values; `on_sample` is called for each valid
/// sample on the Fast DDS listener thread (keep it short). The reader is made
/// without a listener, then given one and drained, so that samples that arrive
/// in between (transient local) are not lost; counts the writers matched.
template <class Sample>
class TopicReader : public TopicEndpoint<eprosima::fastdds::dds::DataReader> {
 public:
  using Callback = std::function<void(const Sample&)>;
  explicit TopicReader(DdsContext& ctx, Callback on_sample = {});
  ~TopicReader();
  int matched_writers() const;

 private:
  class Listener;
  std::unique_ptr<Listener> listener_;
};

/// The order in which a sample thread writes the axes of its group, tick after tick:
/// forwards, then backwards, and so on. Fast DDS 2.9's keyed writer re-arms its
/// offered-deadline timer only at a write of the instance whose deadline comes first,
/// which is the instance written first in the tick before: written last in this tick,
/// it re-arms once per tick, however many axes the group has (in one fixed order every
/// write would re-arm: each makes the next axis the first due). Readers that request a
/// deadline gain the same (Fast DDS's reader does the same per received sample).
class GroupWriteOrder {
 public:
  explicit GroupWriteOrder(std::size_t n) : n_(n) {}
  /// Starts a tick: the next n() calls of at(k), k = 0..n-1, give the members' indices.
  void next_tick() { backwards_ = !backwards_; }
  std::size_t at(std::size_t k) const { return backwards_ ? n_ - 1 - k : k; }
  std::size_t n() const { return n_; }

 private:
  std::size_t n_;
  bool backwards_ = true;  ///< the first tick goes forwards
};

/// Writer of ve/diagnostics (about 10 Hz per axis, reliable keep-last).
class DiagnosticsWriter : public TopicWriter<ve::dds::Diagnostics> { public: using TopicWriter::TopicWriter; };

/// Writer of ve/axis_description (reliable, transient-local).
class DescriptionWriter : public TopicWriter<ve::dds::AxisDescription> { public: using TopicWriter::TopicWriter; };

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
  std::uint64_t diagnostics_received = 0;
  ve::dds::Diagnostics diagnostics{};     ///< the last one (valid when diagnostics_received > 0)
};

/// Reader of the state, description and diagnostics topics with per-axis
/// statistics; optional callbacks per sample (called on the Fast DDS listener thread).
class StateReader {
 public:
  using Callback = std::function<void(const ve::dds::EncoderState&)>;
  using DiagnosticsCallback = std::function<void(const ve::dds::Diagnostics&)>;
  /// deadline_ms > 0: requested deadline of the state stream; <= 0: none requested.
  StateReader(DdsContext& ctx, double deadline_ms, Callback on_sample = {}, DiagnosticsCallback on_diagnostics = {});
  ~StateReader();
  bool ok() const {
    return state_reader_ != nullptr && description_reader_ != nullptr && diagnostics_reader_ != nullptr;
  }

  std::vector<AxisStats> snapshot();
  /// Requested deadline periods missed, all axes: whole periods without a sample of an
  /// axis, counted by this reader (not requested of Fast DDS: see the constructor).
  std::uint64_t deadline_missed_total() const;
  int matched_writers() const;
  int matched_diagnostics_writers() const;
  std::uint64_t total_received() const;
  /// State samples Fast DDS knows were sent and never arrived (gaps in the writers' RTPS
  /// sequence numbers), all axes: lost between the writer and this reader.
  std::uint64_t samples_lost() const;
  std::uint64_t diagnostics_received() const;

 private:
  class Listener;
  friend class Listener;
  DdsContext& ctx_;
  std::unique_ptr<Listener> listener_;
  eprosima::fastdds::dds::DataReader* state_reader_ = nullptr;
  eprosima::fastdds::dds::DataReader* description_reader_ = nullptr;
  eprosima::fastdds::dds::DataReader* diagnostics_reader_ = nullptr;
};

// ------------------------------------------------------------- calibration

/// Reader of ve/calibration_command (run side: reliable, keep all, volatile).
class CalibrationCommandReader : public TopicReader<ve::dds::CalibrationCommand> { public: using TopicReader::TopicReader; };

/// Writer of ve/calibration_status (run side: reliable, transient-local, last per axis).
class CalibrationStatusWriter : public TopicWriter<ve::dds::CalibrationStatus> { public: using TopicWriter::TopicWriter; };

/// Writer of ve/calibration_command (requester side: a tool, an HMI, the tests).
class CalibrationCommandWriter : public TopicWriter<ve::dds::CalibrationCommand> { public: using TopicWriter::TopicWriter; };

/// Reader of ve/calibration_status (requester side). Keeps every status received
/// (in order) and the last one per axis; a late joiner gets the last status of
/// each axis (transient local). `on_status` runs on the Fast DDS listener thread.
class CalibrationStatusReader {
 public:
  using Callback = std::function<void(const ve::dds::CalibrationStatus&)>;
  explicit CalibrationStatusReader(DdsContext& ctx, Callback on_status = {});
  bool ok() const { return reader_.ok(); }
  int matched_writers() const { return reader_.matched_writers(); }
  std::vector<ve::dds::CalibrationStatus> received();
  /// False when no status of this axis has arrived.
  bool last(std::uint32_t axis_id, ve::dds::CalibrationStatus& out);

 private:
  void keep(const ve::dds::CalibrationStatus& s);
  Callback on_status_;
  std::mutex mutex_;
  std::vector<ve::dds::CalibrationStatus> all_;
  std::map<std::uint32_t, ve::dds::CalibrationStatus> last_;
  TopicReader<ve::dds::CalibrationStatus> reader_;  ///< last: its callbacks use the members above
};

extern template class TopicWriter<ve::dds::Diagnostics>;
extern template class TopicWriter<ve::dds::AxisDescription>;
extern template class TopicWriter<ve::dds::CalibrationStatus>;
extern template class TopicWriter<ve::dds::CalibrationCommand>;
extern template class TopicReader<ve::dds::CalibrationCommand>;
extern template class TopicReader<ve::dds::CalibrationStatus>;

}  // namespace ve::app
