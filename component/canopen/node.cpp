#include "canopen/node.hpp"

#include <algorithm>
#include <climits>
#include <cmath>
#include <cstring>

#include "core/status.hpp"

namespace ve::canopen {

int bit_size(DataType t) {
  switch (t) {
    case DataType::u8: return 8;
    case DataType::u16: return 16;
    case DataType::u32:
    case DataType::i32: return 32;
    case DataType::vstring: return 0;
  }
  return 0;
}

const char* access_name(Access a) {
  switch (a) {
    case Access::ro: return "ro";
    case Access::rw: return "rw";
    case Access::const_: return "const";
  }
  return "ro";
}

Object& ObjectDictionary::add(std::uint16_t index, std::string name, ObjectKind kind) {
  Object o;
  o.index = index;
  o.name = std::move(name);
  o.kind = kind;
  objects_.push_back(std::move(o));
  return objects_.back();
}

Entry* ObjectDictionary::find(std::uint16_t index, std::uint8_t sub) {
  for (auto& o : objects_)
    if (o.index == index)
      for (auto& e : o.entries)
        if (e.sub == sub) return &e;
  return nullptr;
}
const Entry* ObjectDictionary::find(std::uint16_t index, std::uint8_t sub) const {
  return const_cast<ObjectDictionary*>(this)->find(index, sub);
}
const Object* ObjectDictionary::object(std::uint16_t index) const {
  for (const auto& o : objects_)
    if (o.index == index) return &o;
  return nullptr;
}

std::uint16_t alarms_of(const AxisSnapshot& s) {
  std::uint16_t a = 0;
  if (!s.present || !(s.status & core::status::kValid)) a |= alarm::kPositionError;
  if (s.status & (0xFFu << core::status::kHallFaultShift)) a |= alarm::kHallFault;
  if (s.status & core::status::kAccelFault) a |= alarm::kAccelFault;
  return a;
}

std::uint16_t warnings_of(const AxisSnapshot& s) {
  std::uint16_t w = 0;
  if (!(s.status & core::status::kHomed)) w |= warning::kNotHomed;
  if (!(s.status & core::status::kCalibrated)) w |= warning::kNotCalibrated;
  if (s.status & core::status::kDegraded) w |= warning::kDegraded;
  if (s.status & core::status::kOutOfTravel) w |= warning::kOutOfTravel;
  return w;
}

namespace {

Entry var(std::uint16_t index, std::uint8_t sub, const char* name, DataType type, Access access, std::uint32_t value,
          bool mappable = false) {
  Entry e;
  e.index = index;
  e.sub = sub;
  e.name = name;
  e.type = type;
  e.access = access;
  e.value = e.default_value = value;
  e.pdo_mappable = mappable;
  e.communication = index >= 0x1000 && index < 0x2000;
  if (type == DataType::u8) e.max = 0xFF;
  if (type == DataType::u16) e.max = 0xFFFF;
  return e;
}

Entry text(std::uint16_t index, const char* name, const std::string& value) {
  Entry e = var(index, 0, name, DataType::vstring, Access::const_, 0);
  e.text = value;
  return e;
}

std::uint32_t mapping_of(Mapped m) { return m == Mapped::position ? 0x60040020u : 0x60300120u; }

void put_u32(std::uint8_t* p, std::uint32_t v) {
  for (int i = 0; i < 4; ++i) p[i] = static_cast<std::uint8_t>(v >> (8 * i));
}
std::uint32_t get_u32(const std::uint8_t* p) {
  return static_cast<std::uint32_t>(p[0]) | static_cast<std::uint32_t>(p[1]) << 8 |
         static_cast<std::uint32_t>(p[2]) << 16 | static_cast<std::uint32_t>(p[3]) << 24;
}

Frame frame(std::uint32_t id, std::uint8_t len) {
  Frame f;
  f.id = id;
  f.len = len;
  return f;
}

constexpr std::int64_t kMs = 1000000;

}  // namespace

ObjectDictionary make_dictionary(const NodeConfig& cfg) {
  ObjectDictionary od;
  const std::uint32_t id = cfg.node_id;
  od.add(0x1000, "Device type", ObjectKind::var).entries = {
      var(0x1000, 0, "Device type", DataType::u32, Access::ro, kDeviceType)};
  od.add(0x1001, "Error register", ObjectKind::var).entries = {
      var(0x1001, 0, "Error register", DataType::u8, Access::ro, 0)};
  od.add(0x1005, "COB-ID SYNC", ObjectKind::var).entries = {
      var(0x1005, 0, "COB-ID SYNC", DataType::u32, Access::ro, 0x80)};
  od.add(0x1008, "Manufacturer device name", ObjectKind::var).entries = {
      text(0x1008, "Manufacturer device name", cfg.device_name)};
  od.add(0x1009, "Manufacturer hardware version", ObjectKind::var).entries = {
      text(0x1009, "Manufacturer hardware version", cfg.hardware_version)};
  od.add(0x100A, "Manufacturer software version", ObjectKind::var).entries = {
      text(0x100A, "Manufacturer software version", cfg.software_version)};
  od.add(0x1014, "COB-ID EMCY", ObjectKind::var).entries = {
      var(0x1014, 0, "COB-ID EMCY", DataType::u32, Access::ro, 0x80 + id)};
  od.add(0x1015, "Inhibit time EMCY", ObjectKind::var).entries = {
      var(0x1015, 0, "Inhibit time EMCY", DataType::u16, Access::rw, 1000)};  // 100 us units: 100 ms
  od.add(0x1017, "Producer heartbeat time", ObjectKind::var).entries = {
      var(0x1017, 0, "Producer heartbeat time", DataType::u16, Access::rw, cfg.heartbeat_ms)};
  od.add(0x1018, "Identity object", ObjectKind::record).entries = {
      var(0x1018, 0, "Highest sub-index supported", DataType::u8, Access::const_, 4),
      var(0x1018, 1, "Vendor-ID", DataType::u32, Access::ro, cfg.vendor_id),
      var(0x1018, 2, "Product code", DataType::u32, Access::ro, cfg.product_code),
      var(0x1018, 3, "Revision number", DataType::u32, Access::ro, cfg.revision),
      var(0x1018, 4, "Serial number", DataType::u32, Access::ro, cfg.serial)};
  {
    Entry cob = var(0x1800, 1, "COB-ID used by TPDO", DataType::u32, Access::rw, 0x180 + id);
    Entry type = var(0x1800, 2, "Transmission type", DataType::u8, Access::rw, cfg.transmission_type);
    od.add(0x1800, "TPDO communication parameter 1", ObjectKind::record).entries = {
        var(0x1800, 0, "Highest sub-index supported", DataType::u8, Access::const_, 2), cob, type};
  }
  {
    Object& m = od.add(0x1A00, "TPDO mapping parameter 1", ObjectKind::record);
    Entry n = var(0x1A00, 0, "Number of mapped objects", DataType::u8, Access::rw,
                  static_cast<std::uint32_t>(cfg.tpdo_mapping.size()));
    n.max = 2;
    m.entries.push_back(n);
    for (std::uint8_t i = 1; i <= 2; ++i) {
      const std::uint32_t v = i <= cfg.tpdo_mapping.size() ? mapping_of(cfg.tpdo_mapping[i - 1u]) : 0u;
      m.entries.push_back(var(0x1A00, i, i == 1 ? "Mapping entry 1" : "Mapping entry 2", DataType::u32, Access::rw, v));
    }
  }
  {
    Entry p = var(0x6000, 0, "Operating parameters", DataType::u16, Access::rw, cfg.reverse ? 1u : 0u);
    p.max = 1;  // bit 0 code sequence; scaling and the other bits are not supported
    od.add(0x6000, "Operating parameters", ObjectKind::var).entries = {p};
  }
  od.add(0x6004, "Position value", ObjectKind::var).entries = {
      var(0x6004, 0, "Position value", DataType::u32, Access::ro, 0, true)};
  od.add(0x6005, "Linear encoder measuring step settings", ObjectKind::record).entries = {
      var(0x6005, 0, "Highest sub-index supported", DataType::u8, Access::const_, 2),
      var(0x6005, 1, "Position step setting", DataType::u32, Access::ro, cfg.step_nm),
      var(0x6005, 2, "Speed step setting", DataType::u32, Access::ro, cfg.step_nm)};
  od.add(0x6030, "Speed value", ObjectKind::array).entries = {
      var(0x6030, 0, "Highest sub-index supported", DataType::u8, Access::const_, 1),
      var(0x6030, 1, "Speed value channel 1", DataType::i32, Access::ro, 0, true)};
  od.add(0x6200, "Cyclic timer", ObjectKind::var).entries = {
      var(0x6200, 0, "Cyclic timer", DataType::u16, Access::rw, cfg.cyclic_timer_ms)};
  od.add(0x6500, "Operating status", ObjectKind::var).entries = {
      var(0x6500, 0, "Operating status", DataType::u16, Access::ro, cfg.reverse ? 1u : 0u)};
  od.add(0x6501, "Measuring step", ObjectKind::var).entries = {
      var(0x6501, 0, "Measuring step", DataType::u32, Access::ro, cfg.step_nm)};
  od.add(0x6503, "Alarms", ObjectKind::var).entries = {
      var(0x6503, 0, "Alarms", DataType::u16, Access::ro, alarm::kPositionError, true)};
  od.add(0x6504, "Supported alarms", ObjectKind::var).entries = {
      var(0x6504, 0, "Supported alarms", DataType::u16, Access::ro, alarm::kSupported)};
  od.add(0x6505, "Warnings", ObjectKind::var).entries = {
      var(0x6505, 0, "Warnings", DataType::u16, Access::ro, warning::kNotHomed | warning::kNotCalibrated, true)};
  od.add(0x6506, "Supported warnings", ObjectKind::var).entries = {
      var(0x6506, 0, "Supported warnings", DataType::u16, Access::ro, warning::kSupported)};
  return od;
}

// ---------------------------------------------------------------------------

Node::Node(NodeConfig cfg, const SnapshotBox* box) : cfg_(std::move(cfg)), box_(box), od_(make_dictionary(cfg_)) {}

void Node::start(std::int64_t mono_ns, Outbox& out) { boot(mono_ns, out); }

void Node::boot(std::int64_t mono_ns, Outbox& out) {
  state_ = NmtState::initialising;
  transfer_ = Transfer::none;
  Frame f = frame(0x700 + cfg_.node_id, 1);
  f.data[0] = 0x00;  // boot-up
  out.push(f);
  enter(NmtState::pre_operational, mono_ns);
  const std::uint32_t hb = od_.find(0x1017, 0)->value;
  next_heartbeat_ns_ = mono_ns + static_cast<std::int64_t>(hb) * kMs;
  last_alarms_ = 0;
  last_hall_mask_ = 0;
  emcy_inhibit_until_ns_ = 0;
}

void Node::reset_communication() {
  for (auto& o : od_.objects())
    for (auto& e : o.entries)
      if (e.communication && e.type != DataType::vstring) e.value = e.default_value;
}

void Node::reset_application() {
  for (auto& o : od_.objects())
    for (auto& e : o.entries)
      if (!e.communication && e.type != DataType::vstring) e.value = e.default_value;
}

void Node::enter(NmtState s, std::int64_t mono_ns) {
  if (s == NmtState::operational && state_ != NmtState::operational) {
    sync_count_ = 0;
    next_cyclic_ns_ = mono_ns;
  }
  if (s != state_) transfer_ = Transfer::none;
  state_ = s;
}

std::int32_t Node::position_steps(const AxisSnapshot& s, std::int64_t t_ns) const {
  const double sign = (od_.find(0x6000, 0)->value & 1u) ? -1.0 : 1.0;
  const double steps = sign * propagate_position(s, t_ns) * 1e9 / static_cast<double>(cfg_.step_nm);
  return static_cast<std::int32_t>(std::llround(std::clamp(steps, double(INT32_MIN), double(INT32_MAX))));
}

std::int32_t Node::speed_steps(const AxisSnapshot& s, std::int64_t t_ns) const {
  const double sign = (od_.find(0x6000, 0)->value & 1u) ? -1.0 : 1.0;
  const double steps = sign * propagate_velocity(s, t_ns) * 1e9 / static_cast<double>(cfg_.step_nm);
  return static_cast<std::int32_t>(std::llround(std::clamp(steps, double(INT32_MIN), double(INT32_MAX))));
}

void Node::refresh(std::int64_t rt_ns) {
  // The estimate current at rt_ns (a SYNC handled late still gets the position at
  // its reception instant, not one propagated back from a newer estimate).
  AxisSnapshot s;
  if (box_) box_->read_at(rt_ns, s);
  if (s.present && s.t_ns > rt_ns) ++counters_.stale_reads;  // every estimate kept is newer
  const std::uint16_t alarms = alarms_of(s);
  od_.find(0x6503, 0)->value = alarms;
  od_.find(0x6505, 0)->value = warnings_of(s);
  od_.find(0x1001, 0)->value = alarms ? 0x21u : 0u;  // generic + device profile specific
  od_.find(0x6500, 0)->value = od_.find(0x6000, 0)->value;
  if (s.present) {
    od_.find(0x6004, 0)->value = static_cast<std::uint32_t>(position_steps(s, rt_ns));
    od_.find(0x6030, 1)->value = static_cast<std::uint32_t>(speed_steps(s, rt_ns));
  }
}

void Node::send_tpdo(std::int64_t rt_ns, Outbox& out) {
  const std::uint32_t cob = od_.find(0x1800, 1)->value;
  if (cob & 0x80000000u) return;  // PDO not valid
  refresh(rt_ns);
  Frame f = frame(cob & 0x7FFu, 0);
  const std::uint32_t n = od_.find(0x1A00, 0)->value;
  int bytes = 0;
  for (std::uint8_t i = 1; i <= n; ++i) {
    const std::uint32_t m = od_.find(0x1A00, i)->value;
    const Entry* e = od_.find(static_cast<std::uint16_t>(m >> 16), static_cast<std::uint8_t>(m >> 8));
    const int len = static_cast<int>(m & 0xFF) / 8;
    if (!e || bytes + len > 8) return;
    for (int b = 0; b < len; ++b) f.data[static_cast<std::size_t>(bytes + b)] = static_cast<std::uint8_t>(e->value >> (8 * b));
    bytes += len;
  }
  f.len = static_cast<std::uint8_t>(bytes);
  out.push(f);
  ++counters_.tpdos;
}

void Node::check_alarms(std::int64_t mono_ns, Outbox& out) {
  AxisSnapshot s;  // none yet: position error
  if (box_) box_->read(s);
  const std::uint16_t alarms = alarms_of(s);
  const std::uint16_t hall_mask = static_cast<std::uint16_t>((s.status >> core::status::kHallFaultShift) & 0xFFu);
  if (alarms == last_alarms_ && hall_mask == last_hall_mask_) return;
  if (mono_ns < emcy_inhibit_until_ns_) return;  // sent once the inhibit time is over
  std::uint16_t code = emcy::kErrorReset;
  if (alarms & (alarm::kHallFault | alarm::kAccelFault))
    code = emcy::kSensor;
  else if (alarms & alarm::kPositionError)
    code = emcy::kGeneric;
  const std::uint16_t warnings = warnings_of(s);
  Frame f = frame(0x80 + cfg_.node_id, 8);
  f.data[0] = static_cast<std::uint8_t>(code);
  f.data[1] = static_cast<std::uint8_t>(code >> 8);
  f.data[2] = alarms ? 0x21 : 0x00;
  f.data[3] = static_cast<std::uint8_t>(alarms);
  f.data[4] = static_cast<std::uint8_t>(alarms >> 8);
  f.data[5] = static_cast<std::uint8_t>(hall_mask);
  f.data[6] = static_cast<std::uint8_t>(warnings);
  f.data[7] = static_cast<std::uint8_t>(warnings >> 8);
  out.push(f);
  ++counters_.emcys;
  last_alarms_ = alarms;
  last_hall_mask_ = hall_mask;
  emcy_inhibit_until_ns_ = mono_ns + static_cast<std::int64_t>(od_.find(0x1015, 0)->value) * 100000;
}

void Node::on_tick(std::int64_t rt_ns, std::int64_t mono_ns, Outbox& out) {
  if (state_ == NmtState::initialising) return;
  const std::uint32_t hb = od_.find(0x1017, 0)->value;
  if (hb > 0 && mono_ns >= next_heartbeat_ns_) {
    Frame f = frame(0x700 + cfg_.node_id, 1);
    f.data[0] = static_cast<std::uint8_t>(state_);
    out.push(f);
    ++counters_.heartbeats;
    next_heartbeat_ns_ += static_cast<std::int64_t>(hb) * kMs;
    if (next_heartbeat_ns_ <= mono_ns) next_heartbeat_ns_ = mono_ns + static_cast<std::int64_t>(hb) * kMs;
  }
  if (state_ == NmtState::stopped) return;
  check_alarms(mono_ns, out);
  if (state_ != NmtState::operational) return;
  const std::uint32_t type = od_.find(0x1800, 2)->value;
  const std::uint32_t cycle = od_.find(0x6200, 0)->value;
  if ((type == 254 || type == 255) && cycle > 0 && mono_ns >= next_cyclic_ns_) {
    send_tpdo(rt_ns, out);
    next_cyclic_ns_ += static_cast<std::int64_t>(cycle) * kMs;
    if (next_cyclic_ns_ <= mono_ns) next_cyclic_ns_ = mono_ns + static_cast<std::int64_t>(cycle) * kMs;
  }
}

std::int64_t Node::next_due_ns() const {
  std::int64_t due = INT64_MAX;
  if (state_ == NmtState::initialising) return due;
  if (od_.find(0x1017, 0)->value > 0) due = next_heartbeat_ns_;
  const std::uint32_t type = od_.find(0x1800, 2)->value;
  if (state_ == NmtState::operational && (type == 254 || type == 255) && od_.find(0x6200, 0)->value > 0)
    due = std::min(due, next_cyclic_ns_);
  return due;
}

void Node::on_frame(const Frame& f, std::int64_t rx_rt_ns, std::int64_t mono_ns, Outbox& out) {
  if (f.id == 0x000) {  // NMT
    if (f.len != 2 || (f.data[1] != 0 && f.data[1] != cfg_.node_id)) return;
    switch (f.data[0]) {
      case 0x01: enter(NmtState::operational, mono_ns); break;
      case 0x02: enter(NmtState::stopped, mono_ns); break;
      case 0x80: enter(NmtState::pre_operational, mono_ns); break;
      case 0x81:
        reset_application();
        reset_communication();
        boot(mono_ns, out);
        break;
      case 0x82:
        reset_communication();
        boot(mono_ns, out);
        break;
      default: break;
    }
    return;
  }
  if (state_ == NmtState::stopped || state_ == NmtState::initialising) return;
  if (f.id == (od_.find(0x1005, 0)->value & 0x7FFu)) {  // SYNC
    if (f.len > 1) return;
    ++counters_.syncs;
    if (state_ != NmtState::operational) return;
    const std::uint32_t type = od_.find(0x1800, 2)->value;
    if (type >= 1 && type <= 240 && ++sync_count_ >= type) {
      sync_count_ = 0;
      send_tpdo(rx_rt_ns, out);
    }
    return;
  }
  if (f.id == 0x600u + cfg_.node_id) on_sdo(f, rx_rt_ns, out);
}

// ---------------------------------------------------------------------------
// SDO server

void Node::sdo_abort(std::uint16_t index, std::uint8_t sub, std::uint32_t code, Outbox& out) {
  Frame r = frame(0x580 + cfg_.node_id, 8);
  r.data[0] = 0x80;
  r.data[1] = static_cast<std::uint8_t>(index);
  r.data[2] = static_cast<std::uint8_t>(index >> 8);
  r.data[3] = sub;
  put_u32(&r.data[4], code);
  out.push(r);
  transfer_ = Transfer::none;
  ++counters_.sdo_aborts;
}

void Node::begin_transfer(Transfer direction, std::uint16_t index, std::uint8_t sub, bool size_known,
                          std::size_t size) {
  transfer_ = direction;
  t_index_ = index;
  t_sub_ = sub;
  toggle_ = 0;
  t_done_ = 0;
  t_size_known_ = size_known;
  t_size_ = size;
}

std::uint32_t Node::check_segment(Transfer direction, std::uint8_t command) const {
  if (transfer_ != direction) return abort_code::kCommand;
  if (((command >> 4) & 1u) != toggle_) return abort_code::kToggle;
  return 0;
}

std::uint32_t Node::read_value(const Entry& e, std::uint8_t* bytes, std::size_t& size) const {
  if (e.type == DataType::vstring) {
    size = std::min(e.text.size(), t_buf_.size());
    std::memcpy(bytes, e.text.data(), size);
    return 0;
  }
  size = static_cast<std::size_t>(bit_size(e.type) / 8);
  for (std::size_t i = 0; i < size; ++i) bytes[i] = static_cast<std::uint8_t>(e.value >> (8 * i));
  return 0;
}

std::uint32_t Node::check_write(Entry& e, std::uint32_t value, std::size_t size) const {
  if (e.access != Access::rw) return abort_code::kReadOnly;
  const std::size_t want = static_cast<std::size_t>(bit_size(e.type) / 8);
  if (size > want) return abort_code::kLengthHigh;
  if (size < want) return abort_code::kLengthLow;
  if (value < e.min || value > e.max) return abort_code::kRange;
  if (e.index == 0x1800 && e.sub == 2 && !((value >= 1 && value <= 240) || value == 254 || value == 255))
    return abort_code::kRange;
  if (e.index == 0x1800 && e.sub == 1 && (value & 0x3FFFF800u) != 0) return abort_code::kRange;
  if (e.index == 0x1A00) {
    if (state_ != NmtState::pre_operational) return abort_code::kState;
    const std::uint32_t n_now = od_.find(0x1A00, 0)->value;
    if (e.sub != 0) {
      if (n_now != 0) return abort_code::kState;  // sub-index 0 must be 0 while entries change
      if (value == 0) return 0;
      const Entry* t = od_.find(static_cast<std::uint16_t>(value >> 16), static_cast<std::uint8_t>(value >> 8));
      if (!t) return abort_code::kNoObject;
      if (!t->pdo_mappable || static_cast<int>(value & 0xFF) != bit_size(t->type)) return abort_code::kNotMappable;
      return 0;
    }
    int bits = 0;
    for (std::uint8_t i = 1; i <= value; ++i) {
      const std::uint32_t m = od_.find(0x1A00, i)->value;
      if (m == 0) return abort_code::kNotMappable;
      bits += static_cast<int>(m & 0xFF);
    }
    if (bits > 64) return abort_code::kPdoLength;
  }
  return 0;
}

std::uint32_t Node::write_entry(Entry& e, std::uint32_t value, std::size_t size) {
  const std::uint32_t code = check_write(e, value, size);
  if (code) return code;
  e.value = value;
  if (e.index == 0x6000) od_.find(0x6500, 0)->value = value;
  return 0;
}

void Node::on_sdo(const Frame& f, std::int64_t rt_ns, Outbox& out) {
  ++counters_.sdo_requests;
  if (f.len != 8) return;  // CiA 301: SDO frames have 8 bytes
  const std::uint8_t ccs = f.data[0] >> 5;
  const auto index = static_cast<std::uint16_t>(f.data[1] | f.data[2] << 8);
  const std::uint8_t sub = f.data[3];
  Frame r = frame(0x580 + cfg_.node_id, 8);

  auto lookup = [&](Entry*& e) -> std::uint32_t {
    e = od_.find(index, sub);
    if (e) return 0;
    return od_.object(index) ? abort_code::kNoSubindex : abort_code::kNoObject;
  };

  switch (ccs) {
    case 1: {  // initiate download
      Entry* e = nullptr;
      if (const std::uint32_t c = lookup(e)) return sdo_abort(index, sub, c, out);
      if (e->access != Access::rw) return sdo_abort(index, sub, abort_code::kReadOnly, out);
      const bool expedited = f.data[0] & 0x02;
      const bool sized = f.data[0] & 0x01;
      if (expedited) {
        const std::size_t size = sized ? 4u - ((f.data[0] >> 2) & 0x3u) : static_cast<std::size_t>(bit_size(e->type) / 8);
        std::uint32_t v = 0;
        for (std::size_t i = 0; i < size; ++i) v |= static_cast<std::uint32_t>(f.data[4 + i]) << (8 * i);
        if (const std::uint32_t c = write_entry(*e, v, size)) return sdo_abort(index, sub, c, out);
      } else {
        begin_transfer(Transfer::download, index, sub, sized, sized ? get_u32(&f.data[4]) : 0);
        if (t_size_ > t_buf_.size()) return sdo_abort(index, sub, abort_code::kLengthHigh, out);
      }
      r.data[0] = 0x60;
      std::memcpy(&r.data[1], &f.data[1], 3);
      out.push(r);
      return;
    }
    case 0: {  // download segment
      if (const std::uint32_t c = check_segment(Transfer::download, f.data[0])) return sdo_abort(t_index_, t_sub_, c, out);
      const std::size_t n = 7u - ((f.data[0] >> 1) & 0x7u);
      if (t_done_ + n > t_buf_.size()) return sdo_abort(t_index_, t_sub_, abort_code::kLengthHigh, out);
      std::memcpy(&t_buf_[t_done_], &f.data[1], n);
      t_done_ += n;
      r.data[0] = static_cast<std::uint8_t>(0x20 | (toggle_ << 4));
      if (f.data[0] & 0x01) {  // last segment
        transfer_ = Transfer::none;
        if (t_size_known_ && t_done_ != t_size_) return sdo_abort(t_index_, t_sub_, abort_code::kLength, out);
        Entry* e = od_.find(t_index_, t_sub_);
        if (!e || e->type == DataType::vstring) return sdo_abort(t_index_, t_sub_, abort_code::kReadOnly, out);
        std::uint32_t v = 0;
        for (std::size_t i = 0; i < std::min<std::size_t>(t_done_, 4); ++i) v |= static_cast<std::uint32_t>(t_buf_[i]) << (8 * i);
        if (const std::uint32_t c = write_entry(*e, v, t_done_)) return sdo_abort(t_index_, t_sub_, c, out);
      }
      toggle_ ^= 1u;
      out.push(r);
      return;
    }
    case 2: {  // initiate upload
      Entry* e = nullptr;
      if (const std::uint32_t c = lookup(e)) return sdo_abort(index, sub, c, out);
      refresh(rt_ns);
      std::size_t size = 0;
      read_value(*e, t_buf_.data(), size);
      std::memcpy(&r.data[1], &f.data[1], 3);
      if (size <= 4 && size > 0) {
        r.data[0] = static_cast<std::uint8_t>(0x43 | ((4 - size) << 2));
        std::memcpy(&r.data[4], t_buf_.data(), size);
      } else {
        r.data[0] = 0x41;
        put_u32(&r.data[4], static_cast<std::uint32_t>(size));
        begin_transfer(Transfer::upload, index, sub, true, size);
      }
      out.push(r);
      return;
    }
    case 3: {  // upload segment
      if (const std::uint32_t c = check_segment(Transfer::upload, f.data[0])) return sdo_abort(t_index_, t_sub_, c, out);
      const std::size_t n = std::min<std::size_t>(7, t_size_ - t_done_);
      const bool last = t_done_ + n >= t_size_;
      r.data[0] = static_cast<std::uint8_t>((toggle_ << 4) | ((7 - n) << 1) | (last ? 1 : 0));
      std::memcpy(&r.data[1], &t_buf_[t_done_], n);
      t_done_ += n;
      toggle_ ^= 1u;
      if (last) transfer_ = Transfer::none;
      out.push(r);
      return;
    }
    case 4:  // abort from the client
      transfer_ = Transfer::none;
      return;
    default: return sdo_abort(index, sub, abort_code::kCommand, out);
  }
}

}  // namespace ve::canopen
