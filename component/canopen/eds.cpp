// The EDS (CiA 306 electronic data sheet) of a node, written from the same
// dictionary the node serves (make_dictionary), so the two cannot differ.
#include <cstdio>
#include <sstream>

#include "canopen/node.hpp"

namespace ve::canopen {

namespace {

std::string hex(std::uint32_t v, int digits) {
  char buf[16];
  std::snprintf(buf, sizeof buf, "0x%0*X", digits, v);
  return buf;
}

std::string section_name(std::uint16_t index) {
  char buf[8];
  std::snprintf(buf, sizeof buf, "%04X", index);
  return buf;
}

void write_entry(std::ostringstream& o, const Entry& e, const std::string& section, const std::string& name) {
  o << "[" << section << "]\n";
  o << "ParameterName=" << name << "\n";
  o << "ObjectType=0x7\n";
  o << "DataType=" << hex(static_cast<std::uint16_t>(e.type), 4) << "\n";
  o << "AccessType=" << access_name(e.access) << "\n";
  if (e.type == DataType::vstring)
    o << "DefaultValue=" << e.text << "\n";
  else if (e.index == 0x1800 && e.sub == 1)
    o << "DefaultValue=$NODEID+0x180\n";
  else if (e.index == 0x1014)
    o << "DefaultValue=$NODEID+0x80\n";
  else if (e.type == DataType::i32)
    o << "DefaultValue=" << static_cast<std::int32_t>(e.default_value) << "\n";
  else
    o << "DefaultValue=" << hex(e.default_value, bit_size(e.type) / 4) << "\n";
  o << "PDOMapping=" << (e.pdo_mappable ? 1 : 0) << "\n\n";
}

}  // namespace

std::string write_eds(const NodeConfig& cfg, const std::string& file_name, const std::string& description) {
  const ObjectDictionary od = make_dictionary(cfg);
  std::ostringstream o;
  o << "; CiA 306 electronic data sheet of a virtual encoder node (CiA 406 linear absolute encoder).\n"
    << "; Written by `virtual-encoder eds` from the object dictionary the node serves.\n\n";
  o << "[FileInfo]\n"
    << "FileName=" << file_name << "\n"
    << "FileVersion=1\nFileRevision=0\nEDSVersion=4.0\n"
    << "Description=" << description << "\n"
    << "CreatedBy=virtual-encoder " << cfg.software_version << "\n\n";
  o << "[DeviceInfo]\n"
    << "VendorName=Virtual Encoder\nVendorNumber=" << hex(cfg.vendor_id, 8) << "\n"
    << "ProductName=" << cfg.device_name << "\nProductNumber=" << hex(cfg.product_code, 8) << "\n"
    << "RevisionNumber=" << hex(cfg.revision, 8) << "\nOrderCode=\n";
  for (int kbps : {10, 20, 50, 125, 250, 500, 800, 1000})
    o << "BaudRate_" << kbps << "=" << (static_cast<std::uint32_t>(kbps) == cfg.bitrate_kbps ? 1 : 0) << "\n";
  o << "SimpleBootUpMaster=0\nSimpleBootUpSlave=1\nGranularity=8\nDynamicChannelsSupported=0\n"
    << "GroupMessaging=0\nNrOfRXPDO=0\nNrOfTXPDO=1\nLSS_Supported=0\n\n";
  o << "[DummyUsage]\n";
  for (int i = 1; i <= 7; ++i) o << "Dummy000" << i << "=0\n";
  o << "\n[Comments]\nLines=3\n"
    << "Line1=Node-ID " << static_cast<int>(cfg.node_id) << ", bit rate " << cfg.bitrate_kbps << " kbit/s\n"
    << "Line2=6004h position and 6030h:01 speed in measuring steps of " << cfg.step_nm << " nm (per second)\n"
    << "Line3=TPDO1: transmission type 1-240 every n-th SYNC (position at the SYNC instant), 254/255 every 6200h ms\n\n";

  auto list = [&](const char* name, auto pred) {
    std::vector<std::uint16_t> ids;
    for (const auto& obj : od.objects())
      if (pred(obj.index)) ids.push_back(obj.index);
    o << "[" << name << "]\nSupportedObjects=" << ids.size() << "\n";
    for (std::size_t i = 0; i < ids.size(); ++i) o << (i + 1) << "=" << hex(ids[i], 4) << "\n";
    o << "\n";
  };
  auto mandatory = [](std::uint16_t i) { return i == 0x1000 || i == 0x1001 || i == 0x1018; };
  list("MandatoryObjects", mandatory);
  list("OptionalObjects", [&](std::uint16_t i) { return !mandatory(i); });
  o << "[ManufacturerObjects]\nSupportedObjects=0\n\n";

  for (const auto& obj : od.objects()) {
    const std::string sec = section_name(obj.index);
    if (obj.kind == ObjectKind::var) {
      write_entry(o, obj.entries.front(), sec, obj.name);
      continue;
    }
    o << "[" << sec << "]\nParameterName=" << obj.name << "\nObjectType=" << hex(static_cast<std::uint8_t>(obj.kind), 1)
      << "\nSubNumber=" << obj.entries.size() << "\n\n";
    for (const auto& e : obj.entries) {
      char sub[16];
      std::snprintf(sub, sizeof sub, "%ssub%X", sec.c_str(), e.sub);
      write_entry(o, e, sub, e.name);
    }
  }
  return o.str();
}

}  // namespace ve::canopen
