// A CiA 406 linear absolute encoder on CiA 301: object dictionary, NMT slave,
// heartbeat producer, SDO server (expedited and segmented), SYNC consumer, TPDO1
// (cyclic or every n-th SYNC) and EMCY producer.
//
// Debian 12 ships no CANopen stack (no lely-core, no CANopenNode package), so this is
// a compact slave written for the product. It is pure protocol logic: frames in,
// frames out, times passed in by the caller; no socket, no thread, no clock read.
// The SocketCAN side (component/app/canopen_io.*) only moves frames.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "canopen/snapshot.hpp"

namespace ve::canopen {

struct Frame {
  std::uint32_t id = 0;  ///< 11-bit identifier
  std::uint8_t len = 0;
  std::array<std::uint8_t, 8> data{};
};

/// Frames a call produced; fixed size, no allocation.
struct Outbox {
  std::array<Frame, 8> frames{};
  int count = 0;
  void push(const Frame& f) {
    if (count < static_cast<int>(frames.size())) frames[static_cast<std::size_t>(count++)] = f;
  }
  void clear() { count = 0; }
};

// ---- object dictionary ----
enum class DataType : std::uint16_t { u8 = 0x0005, u16 = 0x0006, u32 = 0x0007, i32 = 0x0004, vstring = 0x0009 };
enum class Access { ro, rw, const_ };
enum class ObjectKind : std::uint8_t { var = 0x7, array = 0x8, record = 0x9 };

/// One sub-index (a VAR object is one entry with sub-index 0).
struct Entry {
  std::uint16_t index = 0;
  std::uint8_t sub = 0;
  std::string name;
  DataType type = DataType::u32;
  Access access = Access::ro;
  bool pdo_mappable = false;
  std::uint32_t value = 0;       ///< numeric value (i32 as its two's complement bits)
  std::uint32_t default_value = 0;
  std::string text;              ///< vstring value
  std::uint32_t min = 0, max = 0xFFFFFFFFu;  ///< writable range (unsigned; i32 not writable here)
  bool communication = false;    ///< 1000h..1FFFh: restored by reset communication
};

struct Object {
  std::uint16_t index = 0;
  std::string name;
  ObjectKind kind = ObjectKind::var;
  std::vector<Entry> entries;  ///< sub-index order
};

/// Size in bits of a numeric type (0 for a string).
int bit_size(DataType t);
const char* access_name(Access a);  ///< "ro", "rw", "const" (EDS spelling)

class ObjectDictionary {
 public:
  Object& add(std::uint16_t index, std::string name, ObjectKind kind);
  Entry* find(std::uint16_t index, std::uint8_t sub);
  const Entry* find(std::uint16_t index, std::uint8_t sub) const;
  const Object* object(std::uint16_t index) const;
  const std::vector<Object>& objects() const { return objects_; }
  std::vector<Object>& objects() { return objects_; }

 private:
  std::vector<Object> objects_;
};

// ---- SDO abort codes (CiA 301, 7.2.4.3.17), the ones this node sends ----
// An unscoped enumeration: a code is the 32-bit value sent in the abort frame,
// and 0 (no code) means success where a function returns one.
namespace abort_code {
enum : std::uint32_t {
  kToggle = 0x05030000,       ///< toggle bit not alternated
  kCommand = 0x05040001,      ///< command specifier not valid or unknown
  kWriteOnly = 0x06010001,    ///< attempt to read a write-only object
  kReadOnly = 0x06010002,     ///< attempt to write a read-only object
  kNoObject = 0x06020000,     ///< object does not exist in the object dictionary
  kNotMappable = 0x06040041,  ///< object cannot be mapped to the PDO
  kPdoLength = 0x06040042,    ///< the mapped objects would exceed the PDO length
  kLength = 0x06070010,       ///< data type does not match, length does not match
  kLengthHigh = 0x06070012,   ///< ... length too high
  kLengthLow = 0x06070013,    ///< ... length too low
  kNoSubindex = 0x06090011,   ///< sub-index does not exist
  kRange = 0x06090030,        ///< value range of parameter exceeded
  kState = 0x08000022,        ///< data cannot be transferred because of the present device state
};
}  // namespace abort_code

// ---- 6503h alarms / 6505h warnings and EMCY codes ----
namespace alarm {
inline constexpr std::uint16_t kPositionError = 1u << 0;   ///< the position is not VALID
inline constexpr std::uint16_t kHallFault = 1u << 12;      ///< a Hall sensor is flagged (manufacturer bit)
inline constexpr std::uint16_t kAccelFault = 1u << 13;     ///< the accelerometer is missing or saturated
inline constexpr std::uint16_t kSupported = kPositionError | kHallFault | kAccelFault;
}  // namespace alarm
namespace warning {
inline constexpr std::uint16_t kNotHomed = 1u << 5;        ///< reference point not reached
inline constexpr std::uint16_t kNotCalibrated = 1u << 12;  ///< running on the nominal table
inline constexpr std::uint16_t kDegraded = 1u << 13;       ///< fewer Hall sensors than configured
inline constexpr std::uint16_t kOutOfTravel = 1u << 14;    ///< outside the calibrated travel
inline constexpr std::uint16_t kSupported = kNotHomed | kNotCalibrated | kDegraded | kOutOfTravel;
}  // namespace warning
namespace emcy {
inline constexpr std::uint16_t kErrorReset = 0x0000;
inline constexpr std::uint16_t kGeneric = 0x1000;  ///< position error (not VALID)
inline constexpr std::uint16_t kSensor = 0x7300;   ///< Hall sensor or accelerometer fault
}  // namespace emcy

std::uint16_t alarms_of(const AxisSnapshot& s);
std::uint16_t warnings_of(const AxisSnapshot& s);

/// CiA 406 device type: profile 406, encoder type 08h (absolute linear).
inline constexpr std::uint32_t kDeviceType = 0x00080196u;

enum class Mapped : std::uint8_t { position, speed };

struct NodeConfig {
  std::uint8_t node_id = 1;             ///< 1..127
  std::uint32_t bitrate_kbps = 1000;    ///< for the EDS only (the interface's bit rate is set outside)
  std::uint32_t step_nm = 1000;         ///< measuring step (6005h:01, 6501h)
  std::uint16_t cyclic_timer_ms = 0;    ///< 6200h; 0 = no cyclic TPDO
  std::uint8_t transmission_type = 254; ///< 1800h:02: 1..240 every n-th SYNC, 254/255 cyclic (6200h)
  std::uint16_t heartbeat_ms = 100;     ///< 1017h; 0 = none
  std::vector<Mapped> tpdo_mapping{Mapped::position};
  bool reverse = false;                 ///< 6000h bit 0: counting direction reversed
  std::string device_name = "virtual-encoder";
  std::string hardware_version = "virtual (Hall sensors + accelerometer)";
  std::string software_version = "0";
  std::uint32_t vendor_id = 0;          ///< 1018h:01 (no CiA vendor id assigned)
  std::uint32_t product_code = 0x0406;  ///< 1018h:02
  std::uint32_t revision = 0x00010000;  ///< 1018h:03
  std::uint32_t serial = 0;             ///< 1018h:04: the axis id
};

/// The dictionary a node with `cfg` serves after a reset (what the EDS describes).
ObjectDictionary make_dictionary(const NodeConfig& cfg);

enum class NmtState : std::uint8_t { initialising = 0x00, stopped = 0x04, operational = 0x05, pre_operational = 0x7F };

struct NodeCounters {
  std::uint64_t syncs = 0;
  std::uint64_t tpdos = 0;
  std::uint64_t sdo_requests = 0;
  std::uint64_t sdo_aborts = 0;
  std::uint64_t emcys = 0;
  std::uint64_t heartbeats = 0;
  std::uint64_t stale_reads = 0;  ///< no estimate kept at or before the instant asked for
};

class Node {
 public:
  /// `box` may be null (then the node serves "no estimate yet").
  Node(NodeConfig cfg, const SnapshotBox* box);

  /// Power-on: initialisation, boot-up message, pre-operational.
  void start(std::int64_t mono_ns, Outbox& out);
  /// A received frame; `rx_rt_ns` its reception instant on CLOCK_REALTIME (the SYNC
  /// instant), `mono_ns` now on CLOCK_MONOTONIC (timers).
  void on_frame(const Frame& f, std::int64_t rx_rt_ns, std::int64_t mono_ns, Outbox& out);
  /// Timers (heartbeat, cyclic TPDO) and alarm changes (EMCY). Call at least at
  /// next_due_ns(), and often enough for alarms (every few milliseconds).
  void on_tick(std::int64_t rt_ns, std::int64_t mono_ns, Outbox& out);
  /// The next timer due on CLOCK_MONOTONIC (INT64_MAX: none).
  std::int64_t next_due_ns() const;

  NmtState state() const { return state_; }
  const ObjectDictionary& dictionary() const { return od_; }
  const NodeConfig& config() const { return cfg_; }
  const NodeCounters& counters() const { return counters_; }
  /// The last position and velocity sent or served [measuring steps, steps/s].
  std::int32_t position_steps(const AxisSnapshot& s, std::int64_t t_ns) const;
  std::int32_t speed_steps(const AxisSnapshot& s, std::int64_t t_ns) const;

 private:
  void boot(std::int64_t mono_ns, Outbox& out);
  void reset_communication();
  void reset_application();
  void enter(NmtState s, std::int64_t mono_ns);
  void refresh(std::int64_t rt_ns);
  void send_tpdo(std::int64_t rt_ns, Outbox& out);
  void check_alarms(std::int64_t mono_ns, Outbox& out);
  void on_sdo(const Frame& f, std::int64_t rt_ns, Outbox& out);
  void sdo_abort(std::uint16_t index, std::uint8_t sub, std::uint32_t code, Outbox& out);
  // Segmented SDO transfer (CiA 301 7.2.4.3): the initiate request starts one of
  // `size` bytes (upload) or of `size` announced bytes (download, when
  // `size_known`); every segment must belong to a transfer of the same direction
  // and carry the toggle bit expected next, else the abort code to send.
  enum class Transfer { none, download, upload };
  void begin_transfer(Transfer direction, std::uint16_t index, std::uint8_t sub, bool size_known, std::size_t size);
  std::uint32_t check_segment(Transfer direction, std::uint8_t command) const;
  std::uint32_t check_write(Entry& e, std::uint32_t value, std::size_t size) const;
  std::uint32_t write_entry(Entry& e, std::uint32_t value, std::size_t size);
  std::uint32_t read_value(const Entry& e, std::uint8_t* bytes, std::size_t& size) const;

  NodeConfig cfg_;
  const SnapshotBox* box_;
  ObjectDictionary od_;
  NmtState state_ = NmtState::initialising;
  NodeCounters counters_;
  std::int64_t next_heartbeat_ns_ = 0;
  std::int64_t next_cyclic_ns_ = 0;
  std::uint32_t sync_count_ = 0;
  std::uint16_t last_alarms_ = 0;
  std::uint16_t last_hall_mask_ = 0;
  bool emcy_pending_ = false;
  std::int64_t emcy_inhibit_until_ns_ = 0;
  // SDO transfer in progress.
  Transfer transfer_ = Transfer::none;
  std::uint16_t t_index_ = 0;
  std::uint8_t t_sub_ = 0;
  std::uint8_t toggle_ = 0;
  std::array<std::uint8_t, 256> t_buf_{};
  std::size_t t_size_ = 0, t_done_ = 0;
  bool t_size_known_ = false;
};

/// The EDS (CiA 306) of a node with `cfg`.
std::string write_eds(const NodeConfig& cfg, const std::string& file_name, const std::string& description);

}  // namespace ve::canopen
