// DDS Security with real processes over a real DDS stack: a test PKI from
// deploy/security/make-test-pki.sh, `virtual-encoder run` with the encoder
// identity's secure profiles (the machine file's dds.profiles_file), and in the
// same run:
//  - permitted: the monitor identity (`virtual-encoder monitor --csv` and a
//    participant in this process) reads the state and starts a calibration;
//  - unauthenticated: a participant without security reads nothing and its
//    calibration command is never acted on;
//  - authenticated but unpermitted: the intruder identity is admitted to the
//    domain, but its access control refuses it any reader or writer on ve/*;
//  - forged permissions: the intruder identity with a permissions document that
//    grants it all of ve/*, signed by a CA of its own. Its own checks pass, so it
//    has a state reader and a command writer; the encoder does not accept the
//    permissions, so it reads nothing and its calibration command is never acted on.
// "Nothing arrives" is asserted over generous windows in which the permitted
// participants of the same run did receive.
//
// Joining, and Fast DDS 2.9.1 (Debian 12's libfastrtps). Its SecurityManager
// (src/cpp/rtps/security/SecurityManager.cpp) does resend a lost handshake message:
// discovered_participant() arms a TimedEvent per remote participant whose callback,
// resend_handshake_message_token(), re-sends the last request or reply and returns
// true (rearm); on_process_handshake() doubles its period at each step (500 ms ->
// 1 s), with no limit on the number of resends (2.9 has no max_handshake_requests);
// a repeated request makes the replier resend its reply and a repeated reply makes
// the requester resend its final message (process_participant_stateless_message),
// and the crypto tokens travel on a reliable writer. A lost datagram costs about 1 s.
// What 2.9.1 does not survive is a data race: match_builtin_endpoints() and
// match_builtin_key_exchange_endpoints() fill ONE shared temporary Reader/WriterProxyData
// per participant (temp_stateless_*_proxy_data_, temp_volatile_*_proxy_data_) without a
// lock, and a participant calls them from its receive threads (UDP multicast, UDP
// unicast, shared memory) when it discovers or authenticates two participants at
// once. The loser's handshake or key-exchange endpoint can then be matched with another
// participant's GUID or locators; every resend goes the same wrong way, and that pair
// never finishes. Seen here: a `monitor --csv` that met four secure participants at once
// logged "Attempting to add existing reader, updating information" (a writer's
// matched_reader_add() given a GUID it already had) and then only "No key material yet"
// (it held the encoder's crypto handles without their tokens) for 60 s. Upstream
// fixed it in 2.9.2 (eProsima/Fast-DDS#3373, "Replaced SecurityManager temporary
// ProxyDatas with ProxyPools"); Debian 12 ships 2.9.1. A new participant (a new GUID)
// is matched afresh. This process' secure participants also meet each other (their GUID
// prefixes are derived from their certificates by PKI-DH, so Fast DDS' FILTER_SAME_PROCESS
// does not recognise them). The product's `monitor --csv` of the first test meets four
// at once and is started once more if it does not receive (see there). The calibration test
//  - lets its participants join one at a time, the permitted monitor first, each once the
//    previous one is done with the encoder: the encoder (the product) never handshakes
//    with two of them at once, and the monitor meets only the encoder when it joins;
//  - re-creates once, with a note and what it saw, one of its own participants that has
//    not finished with the encoder within the wait (join_once_more below): a joining
//    participant still meets the encoder and this process' earlier ones at once (the
//    intruder: the encoder and the monitor). Twice is a failure.
#include <gtest/gtest.h>

#include <stdlib.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <sstream>
#include <utility>
#include <vector>

#include <fastdds/dds/domain/DomainParticipant.hpp>
#include <fastdds/dds/domain/DomainParticipantFactory.hpp>
#include <fastdds/dds/domain/DomainParticipantListener.hpp>
#include <fastdds/dds/log/Log.hpp>
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
#include "app/dds_io.hpp"
#include "process.hpp"
#include "speed.hpp"
#include "temp_dir.hpp"
#include "test_domain.hpp"

namespace {

namespace fs = std::filesystem;
namespace fdds = eprosima::fastdds::dds;
using eprosima::fastrtps::types::ReturnCode_t;
using namespace std::chrono_literals;
using ve::test::ChildProcess;
using ve::test::wait_until;

constexpr std::uint32_t kAxis = 7;

using ve::test::TempDir;

std::string read(const fs::path& p) {
  std::ifstream in(p);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

void write(const fs::path& p, const std::string& text) { std::ofstream(p) << text; }

/// A shell command run to its end as a child of this test (ChildProcess: it ends with
/// the test); its exit code, -1 if it did not end within two minutes.
int shell(const std::string& command) {
  ChildProcess sh({"/bin/sh", "-c", command}, "/dev/null");
  return sh.wait_exit(120s);
}

bool have_openssl() { return shell("command -v openssl >/dev/null 2>&1") == 0; }

std::string quoted(const fs::path& p) { return "'" + p.string() + "'"; }

/// The test PKI, made once for all tests of this file.
class Pki {
 public:
  static Pki& get() {
    static Pki pki;
    return pki;
  }
  bool ok() const { return ok_; }
  const std::string& error() const { return error_; }
  fs::path dir() const { return dir_.path / "pki"; }
  fs::path profiles(const std::string& id) const { return dir() / id / "dds-profiles-secure.xml"; }
  /// A CA of the intruder's own ("rogue"), the governance signed by it, and a
  /// permissions document for the intruder granting all of ve/*, signed by it.
  fs::path rogue_dir() const { return dir_.path / "rogue"; }

  /// The Fast DDS security properties of an identity, as in its profiles file.
  /// `forged`: the intruder's permissions CA, governance and permissions are the rogue ones.
  std::vector<std::pair<std::string, std::string>> properties(const std::string& id, bool forged = false) const {
    const std::string d = dir().string(), r = rogue_dir().string();
    return {
        {"dds.sec.auth.plugin", "builtin.PKI-DH"},
        {"dds.sec.auth.builtin.PKI-DH.identity_ca", "file://" + d + "/ca/ca.pem"},
        {"dds.sec.auth.builtin.PKI-DH.identity_certificate", "file://" + d + "/" + id + "/cert.pem"},
        {"dds.sec.auth.builtin.PKI-DH.private_key", "file://" + d + "/" + id + "/key.pem"},
        {"dds.sec.access.plugin", "builtin.Access-Permissions"},
        {"dds.sec.access.builtin.Access-Permissions.permissions_ca",
         "file://" + (forged ? r + "/ca.pem" : d + "/ca/ca.pem")},
        {"dds.sec.access.builtin.Access-Permissions.governance",
         "file://" + (forged ? r + "/governance.p7s" : d + "/governance.p7s")},
        {"dds.sec.access.builtin.Access-Permissions.permissions",
         "file://" + (forged ? r + "/permissions.p7s" : d + "/" + id + "/permissions.p7s")},
        {"dds.sec.crypto.plugin", "builtin.AES-GCM-GMAC"},
    };
  }

 private:
  Pki() {
    if (!have_openssl()) return;
    const fs::path script = fs::path(VE_SOURCE_DIR) / "deploy" / "security" / "make-test-pki.sh";
    const fs::path log = dir_.path / "make-test-pki.log";
    const std::string cmd = "bash " + quoted(script) + " " + quoted(dir()) + " >" + quoted(log) + " 2>&1";
    if (shell(cmd) != 0) {
      error_ = "make-test-pki.sh failed:\n" + read(log);
      return;
    }
    // A second run changes no file and says nothing.
    const auto files = [this] {
      std::map<std::string, std::pair<fs::file_time_type, std::string>> m;
      for (const auto& e : fs::recursive_directory_iterator(dir()))
        if (e.is_regular_file()) m[e.path().string()] = {e.last_write_time(), read(e.path())};
      return m;
    };
    const auto before = files();
    if (shell(cmd) != 0 || !read(log).empty() || files() != before) {
      error_ = "make-test-pki.sh is not idempotent and quiet:\n" + read(log);
      return;
    }
    // The properties this test gives its participants are those of the generated profiles.
    for (const std::string id : {"encoder", "monitor", "intruder"}) {
      const std::string xml = read(profiles(id));
      for (const auto& [k, v] : properties(id))
        if (xml.find("<name>" + k + "</name>") == std::string::npos ||
            xml.find("<value>" + v + "</value>") == std::string::npos) {
          error_ = profiles(id).string() + " lacks " + k + " = " + v;
          return;
        }
    }
    // The rogue CA, and with it the governance and the intruder's forged permissions.
    const fs::path r = rogue_dir();
    fs::create_directories(r);
    std::string permissions = read(dir() / "intruder" / "permissions.xml");
    for (std::size_t at; (at = permissions.find("<topic>lab/chat</topic>")) != std::string::npos;)
      permissions.replace(at, 23, "<topic>ve/*</topic>");
    write(r / "permissions.xml", permissions);
    const std::string ca = " -signer " + quoted(r / "ca.pem") + " -inkey " + quoted(r / "ca.key");
    const std::string steps =
        "set -e; cd " + quoted(r) +
        "; openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out ca.key"
        "; openssl req -x509 -new -sha256 -days 30 -key ca.key -out ca.pem -subj '/O=Rogue/CN=Rogue CA'"
        " -addext 'basicConstraints=critical,CA:TRUE' -addext 'keyUsage=critical,keyCertSign,digitalSignature'"
        "; openssl smime -sign -text -md sha256 -in " + quoted(dir() / "governance.xml") +
        " -out governance.p7s" + ca + "; openssl smime -sign -text -md sha256 -in permissions.xml -out permissions.p7s" +
        ca;
    const std::string cmd2 = "(" + steps + ") >" + quoted(log) + " 2>&1";
    if (permissions.find("<topic>ve/*</topic>") == std::string::npos || shell(cmd2) != 0) {
      error_ = "cannot make the forged permissions:\n" + read(log);
      return;
    }
    ok_ = true;
  }
  TempDir dir_;
  bool ok_ = false;
  std::string error_;
};

#define REQUIRE_PKI()                                                      \
  do {                                                                     \
    if (!have_openssl()) GTEST_SKIP() << "openssl not found";              \
    ASSERT_TRUE(Pki::get().ok()) << Pki::get().error();                    \
  } while (0)

/// A machine with one simulated axis (a short copy of the sim-12mm motor, so a
/// calibration sweep is short) using the given profiles file.
fs::path make_machine(const fs::path& dir, const std::string& name, const fs::path& profiles) {
  std::string m = read(fs::path(VE_SOURCE_DIR) / "config" / "motors" / "sim-12mm.yaml");
  m.replace(m.find("motor: sim-12mm"), 15, "motor: short-12");
  m.replace(m.find("travel_m: 1.0"), 13, "travel_m: 0.1");
  write(dir / "short.yaml", m);
  const fs::path machine = dir / (name + ".yaml");
  write(machine,
        "machine: secure-" + name +
            "\n"
            "dds:\n"
            "  profiles_file: " +
            profiles.string() +
            "\n"
            "axes:\n"
            "  - name: x\n"
            "    id: 7\n"
            "    motor: short.yaml\n"
            "    driver:\n"
            "      type: sim\n"
            "      profile: {type: shuttle, start_m: 0.05, min_m: 0.01, max_m: 0.09, max_velocity_mps: 0.05,\n"
            "                max_acceleration_mps2: 1.0}\n"
            "    homing: {mode: startup_position, position_m: 0.05}\n");
  return machine;
}

/// A participant of this process, with or without security (Fast DDS' built-in
/// transports), with the ve/* entities the test asks for, their QoS compatible with
/// the product's (state: best effort; commands: reliable, volatile; status: reliable,
/// transient local).
class Peer {
 public:
  using Properties = std::vector<std::pair<std::string, std::string>>;

  Peer(int domain, const std::string& name, const Properties& properties) {
    auto* factory = fdds::DomainParticipantFactory::get_instance();
    fdds::DomainParticipantQos q = fdds::PARTICIPANT_QOS_DEFAULT;
    q.name(name);
    for (const auto& [k, v] : properties) q.properties().properties().emplace_back(k, v);
    participant_ = factory->create_participant(static_cast<fdds::DomainId_t>(domain), q, &participant_listener_,
                                               fdds::StatusMask::none());
    if (participant_ == nullptr) return;
    fdds::TypeSupport state(new ve::dds::EncoderStatePubSubType());
    fdds::TypeSupport command(new ve::dds::CalibrationCommandPubSubType());
    fdds::TypeSupport status(new ve::dds::CalibrationStatusPubSubType());
    for (auto* t : {&state, &command, &status})
      if (t->register_type(participant_) != ReturnCode_t::RETCODE_OK) return;
    state_topic_ = participant_->create_topic(ve::app::kStateTopic, state.get_type_name(), fdds::TOPIC_QOS_DEFAULT);
    command_topic_ = participant_->create_topic(ve::app::kCalibrationCommandTopic, command.get_type_name(),
                                                fdds::TOPIC_QOS_DEFAULT);
    status_topic_ = participant_->create_topic(ve::app::kCalibrationStatusTopic, status.get_type_name(),
                                               fdds::TOPIC_QOS_DEFAULT);
    publisher_ = participant_->create_publisher(fdds::PUBLISHER_QOS_DEFAULT);
    subscriber_ = participant_->create_subscriber(fdds::SUBSCRIBER_QOS_DEFAULT);
  }
  ~Peer() {
    if (participant_ == nullptr) return;
    participant_->set_listener(nullptr);
    for (auto* r : {state_reader_, status_reader_})
      if (r != nullptr) r->set_listener(nullptr);
    if (command_writer_ != nullptr) command_writer_->set_listener(nullptr);
    participant_->delete_contained_entities();
    fdds::DomainParticipantFactory::get_instance()->delete_participant(participant_);
  }
  Peer(const Peer&) = delete;
  Peer& operator=(const Peer&) = delete;

  bool ok() const {
    return participant_ != nullptr && state_topic_ != nullptr && command_topic_ != nullptr &&
           status_topic_ != nullptr && publisher_ != nullptr && subscriber_ != nullptr;
  }

  /// False when the participant's access control refuses the reader.
  bool read_state() {
    fdds::DataReaderQos q = fdds::DATAREADER_QOS_DEFAULT;
    q.reliability().kind = fdds::BEST_EFFORT_RELIABILITY_QOS;
    q.history().kind = fdds::KEEP_LAST_HISTORY_QOS;
    q.history().depth = 64;
    state_reader_ = subscriber_->create_datareader(
        state_topic_, q, &listener_, fdds::StatusMask::data_available() << fdds::StatusMask::subscription_matched());
    return state_reader_ != nullptr;
  }
  bool write_commands() {
    fdds::DataWriterQos q = fdds::DATAWRITER_QOS_DEFAULT;
    q.reliability().kind = fdds::RELIABLE_RELIABILITY_QOS;
    q.durability().kind = fdds::VOLATILE_DURABILITY_QOS;
    q.history().kind = fdds::KEEP_ALL_HISTORY_QOS;
    command_writer_ =
        publisher_->create_datawriter(command_topic_, q, &writer_listener_, fdds::StatusMask::publication_matched());
    return command_writer_ != nullptr;
  }
  bool read_status() {
    fdds::DataReaderQos q = fdds::DATAREADER_QOS_DEFAULT;
    q.reliability().kind = fdds::RELIABLE_RELIABILITY_QOS;
    q.durability().kind = fdds::TRANSIENT_LOCAL_DURABILITY_QOS;
    q.history().kind = fdds::KEEP_LAST_HISTORY_QOS;
    q.history().depth = 1;
    status_reader_ = subscriber_->create_datareader(
        status_topic_, q, &listener_, fdds::StatusMask::data_available() << fdds::StatusMask::subscription_matched());
    return status_reader_ != nullptr;
  }

  /// A reader of another topic (the same type), for grants outside ve/*.
  bool read_topic(const std::string& name) {
    auto* topic = participant_->create_topic(name, state_topic_->get_type_name(), fdds::TOPIC_QOS_DEFAULT);
    return topic != nullptr && subscriber_->create_datareader(topic, fdds::DATAREADER_QOS_DEFAULT) != nullptr;
  }

  /// Participants outside `local` that authenticated this one and accepted its permissions.
  int admitted_by_others(const std::vector<const Peer*>& local) {
    std::lock_guard<std::mutex> lock(participant_listener_.mutex);
    return outside(participant_listener_.authorized, local);
  }

  /// Participants outside `local` this one discovered.
  int discovered_others(const std::vector<const Peer*>& local) {
    std::lock_guard<std::mutex> lock(participant_listener_.mutex);
    return outside(participant_listener_.discovered, local);
  }

  /// What this participant saw of the others (in this test: of the product's
  /// participants), with the seconds since it was created: for the notes and failures.
  std::string report() {
    std::lock_guard<std::mutex> lock(participant_listener_.mutex);
    const auto list = [](const std::vector<ParticipantListener::Event>& v) {
      std::string s;
      for (const auto& [prefix, at] : v) {
        char t[32];
        std::snprintf(t, sizeof t, " @%.1fs", std::chrono::duration<double>(at).count());
        std::ostringstream g;
        g << prefix;
        s += (s.empty() ? "" : ",") + (" " + g.str()) + t;
      }
      return s.empty() ? std::string(" none") : s;
    };
    std::ostringstream out;
    out << participant_->get_qos().name().to_string() << " (" << participant_->guid().guidPrefix
        << "): discovered" << list(participant_listener_.discovered) << "; authenticated and accepted"
        << list(participant_listener_.authorized) << "; refused" << list(participant_listener_.refused)
        << "; matched: state writers " << listener_.state_matched.load() << ", status writers "
        << listener_.status_matched.load() << ", command readers " << writer_listener_.matched.load();
    return out.str();
  }

  bool send(std::uint32_t command, std::uint64_t request, double sweep_speed = 0.0) {
    ve::dds::CalibrationCommand c;
    c.axis_id(kAxis);
    c.command(command);
    c.request_id(request);
    c.sweep_speed_mps(sweep_speed);
    c.requested_by(participant_->get_qos().name().to_string());
    return command_writer_->write(&c);
  }

  std::uint64_t states_received() const { return listener_.states.load(); }
  int state_writers_matched() const { return listener_.state_matched.load(); }
  int status_writers_matched() const { return listener_.status_matched.load(); }
  int command_readers_matched() const { return writer_listener_.matched.load(); }
  std::vector<ve::dds::CalibrationStatus> statuses() {
    std::lock_guard<std::mutex> lock(listener_.mutex);
    return listener_.statuses;
  }
  bool any_status_of(std::uint64_t request) {
    for (const auto& s : statuses())
      if (s.request_id() == request) return true;
    return false;
  }
  bool status_of(std::uint64_t request, std::uint32_t state, ve::dds::CalibrationStatus& out) {
    for (const auto& s : statuses())
      if (s.request_id() == request && s.state() == state) {
        out = s;
        return true;
      }
    return false;
  }

 private:
  struct ParticipantListener : fdds::DomainParticipantListener {
    using Event = std::pair<eprosima::fastrtps::rtps::GuidPrefix_t, std::chrono::steady_clock::duration>;
    void on_participant_discovery(fdds::DomainParticipant*,
                                  eprosima::fastrtps::rtps::ParticipantDiscoveryInfo&& info) override {
      std::lock_guard<std::mutex> lock(mutex);
      if (info.status == eprosima::fastrtps::rtps::ParticipantDiscoveryInfo::DISCOVERED_PARTICIPANT)
        discovered.emplace_back(info.info.m_guid.guidPrefix, std::chrono::steady_clock::now() - created);
    }
    void onParticipantAuthentication(fdds::DomainParticipant*,
                                     eprosima::fastrtps::rtps::ParticipantAuthenticationInfo&& info) override {
      std::lock_guard<std::mutex> lock(mutex);
      const Event e{info.guid.guidPrefix, std::chrono::steady_clock::now() - created};
      if (info.status == eprosima::fastrtps::rtps::ParticipantAuthenticationInfo::AUTHORIZED_PARTICIPANT)
        authorized.push_back(e);
      else
        refused.push_back(e);
    }
    const std::chrono::steady_clock::time_point created = std::chrono::steady_clock::now();
    std::mutex mutex;
    std::vector<Event> discovered, authorized, refused;
  };
  struct ReaderListener : fdds::DataReaderListener {
    void on_data_available(fdds::DataReader* reader) override {
      fdds::SampleInfo info;
      if (reader->get_topicdescription()->get_name() == ve::app::kStateTopic) {
        ve::dds::EncoderState s;
        while (reader->take_next_sample(&s, &info) == ReturnCode_t::RETCODE_OK)
          if (info.valid_data) states.fetch_add(1);
        return;
      }
      ve::dds::CalibrationStatus s;
      while (reader->take_next_sample(&s, &info) == ReturnCode_t::RETCODE_OK) {
        if (!info.valid_data) continue;
        std::lock_guard<std::mutex> lock(mutex);
        statuses.push_back(s);
      }
    }
    void on_subscription_matched(fdds::DataReader* reader, const fdds::SubscriptionMatchedStatus& s) override {
      if (reader->get_topicdescription()->get_name() == ve::app::kStateTopic)
        state_matched.store(s.current_count);
      else
        status_matched.store(s.current_count);
    }
    std::atomic<std::uint64_t> states{0};
    std::atomic<int> state_matched{0}, status_matched{0};
    std::mutex mutex;
    std::vector<ve::dds::CalibrationStatus> statuses;
  };
  struct WriterListener : fdds::DataWriterListener {
    void on_publication_matched(fdds::DataWriter*, const fdds::PublicationMatchedStatus& s) override {
      matched.store(s.current_count);
    }
    std::atomic<int> matched{0};
  };

  template <class Events>
  static int outside(const Events& events, const std::vector<const Peer*>& local) {
    int n = 0;
    for (const auto& [prefix, at] : events) {
      bool is_local = false;
      for (const auto* p : local) is_local = is_local || p->participant_->guid().guidPrefix == prefix;
      if (!is_local) ++n;
    }
    return n;
  }

  fdds::DomainParticipant* participant_ = nullptr;
  fdds::Topic* state_topic_ = nullptr;
  fdds::Topic* command_topic_ = nullptr;
  fdds::Topic* status_topic_ = nullptr;
  fdds::Publisher* publisher_ = nullptr;
  fdds::Subscriber* subscriber_ = nullptr;
  fdds::DataReader* state_reader_ = nullptr;
  fdds::DataReader* status_reader_ = nullptr;
  fdds::DataWriter* command_writer_ = nullptr;
  ParticipantListener participant_listener_;
  ReaderListener listener_;
  WriterListener writer_listener_;
};

/// CSV rows (one per received sample) in the output of `monitor --csv`.
std::size_t csv_rows(const std::string& log) {
  std::size_t n = 0;
  std::istringstream in(log);
  for (std::string line; std::getline(in, line);)
    if (line.rfind(std::to_string(kAxis) + ",", 0) == 0 && std::count(line.begin(), line.end(), ',') == 13) ++n;
  return n;
}

/// Creates one of this process' participants with `make` and waits until `done` says its
/// handshake (and what follows) with the encoder is over. If it is not within the wait,
/// says so with what the participant saw and creates it once more: a new participant
/// (a new GUID), which Fast DDS 2.9.1 matches afresh (the race at the top of this file).
/// Null, with a failure recorded, when `make` fails or the second one does not finish either.
std::unique_ptr<Peer> join_once_more(const std::string& who, const std::function<std::unique_ptr<Peer>()>& make,
                                     const std::function<bool(Peer&)>& done, const ChildProcess& encoder) {
  const std::chrono::milliseconds wait = ve::test::patience(30s);  // about 30 handshake resends
  for (int attempt = 1; attempt <= 2; ++attempt) {
    std::unique_ptr<Peer> peer = make();
    if (peer == nullptr) return nullptr;  // make() recorded why
    if (wait_until([&] { return done(*peer); }, wait)) {
      if (attempt == 2) std::printf("[ note     ] %s: the second participant finished\n", who.c_str());
      return peer;
    }
    if (attempt == 2) {
      ADD_FAILURE() << who << ": not done with the encoder within " << wait.count() / 1000
                    << " s, twice (two participants, two GUIDs): "
                    << peer->report() << "\n" << encoder.log();
      return nullptr;
    }
    std::printf("[ note     ] %s: not done with the encoder within %lld s; it is re-created once (a new GUID), "
                "as Fast DDS 2.9.1 can leave a pair that met another participant at the same time unmatched "
                "for good (top of dds_security_test.cpp). It saw: %s\n",
                who.c_str(), static_cast<long long>(wait.count() / 1000), peer->report().c_str());
    std::fflush(stdout);
  }
  return nullptr;
}

std::vector<std::string> run_args(const fs::path& machine, int domain) {
  return {VE_BINARY, "run", "--config", machine.string(), "--domain", std::to_string(domain), "--duration", "110"};
}

TEST(DdsSecurity, OnlyThePermittedMonitorReadsTheState) {
  const ve::test::RealTimeSlot real_time;  // needs its CPU to judge what it does (speed.hpp)
  REQUIRE_PKI();
  const Pki& pki = Pki::get();
  TempDir dir;
  const fs::path encoder_machine = make_machine(dir.path, "encoder", pki.profiles("encoder"));
  const fs::path monitor_machine = make_machine(dir.path, "monitor", pki.profiles("monitor"));
  const int domain = ve::test::dds_domain();

  // The denied participants exist before the encoder: they have every chance to see the state.
  Peer open(domain, "unauthenticated", {});
  ASSERT_TRUE(open.ok());
  ASSERT_TRUE(open.read_state());
  Peer intruder(domain, "intruder", pki.properties("intruder"));
  ASSERT_TRUE(intruder.ok()) << "the intruder has a valid identity and permissions: its participant is created";
  // Its access control refuses a reader of ve/encoder_state, and grants what it was granted.
  EXPECT_FALSE(intruder.read_state());
  EXPECT_TRUE(intruder.read_topic("lab/chat"));
  Peer forged(domain, "intruder-forged", pki.properties("intruder", true));
  ASSERT_TRUE(forged.ok());
  ASSERT_TRUE(forged.read_state()) << "its forged permissions grant it ve/* locally";
  // The positive control of the same run.
  auto monitor_peer = std::make_unique<Peer>(domain, "monitor", pki.properties("monitor"));
  ASSERT_TRUE(monitor_peer->ok());
  ASSERT_TRUE(monitor_peer->read_state());

  ChildProcess encoder(run_args(encoder_machine, domain), (dir.path / "run.log").string());
  ASSERT_TRUE(encoder.started());
  // Created before the encoder, it meets it together with three other secure
  // participants: Fast DDS 2.9.1 can leave that pair unmatched for good (top of this
  // file). If it has received nothing within the wait, it is created once more (a new GUID).
  if (!wait_until([&] { return monitor_peer->states_received() > 4000; }, ve::test::patience(30s))) {
    std::printf("[ note     ] the monitor participant received %llu samples (matched %d) within the wait; it is "
                "re-created once (Fast DDS 2.9.1 race, top of dds_security_test.cpp)\n",
                static_cast<unsigned long long>(monitor_peer->states_received()), monitor_peer->state_writers_matched());
    std::fflush(stdout);
    monitor_peer = std::make_unique<Peer>(domain, "monitor", pki.properties("monitor"));
    ASSERT_TRUE(monitor_peer->ok());
    ASSERT_TRUE(monitor_peer->read_state());
  }
  Peer& monitor = *monitor_peer;
  const std::vector<const Peer*> local{&open, &intruder, &forged, &monitor};
  ASSERT_TRUE(wait_until([&] { return monitor.states_received() > 4000; }, ve::test::patience(30s)))
      << "received " << monitor.states_received() << ", matched " << monitor.state_writers_matched() << "\n"
      << encoder.log();
  // The product's monitor with the monitor identity's profiles, as deployed. It joins a
  // domain of five participants, four of them secure: with Fast DDS 2.9.1 it can stay
  // unmatched with the encoder for good (the race at the top of this file; seen once in
  // 12 runs on a loaded 2-core host: its log said "Attempting to add existing reader,
  // updating information" as it met them, then only "No key material yet"). A monitor
  // started again is a new participant, matched afresh: what an operator does (README,
  // "DDS Security"). So it is started again, and said so, if it has not received
  // within 20 s (about 20 handshake resends; normally it receives within 2 s): up to
  // kMonitorStarts times, the last with a longer wait. (Twice in a row, both started once
  // the others were up, in the fresh-clone run of 2026-11-29: each meets the same four
  // secure participants at once, so one more start is worth its 20 s.)
  const std::vector<std::string> csv_args{VE_BINARY, "monitor", "--config", monitor_machine.string(), "--domain",
                                          std::to_string(domain), "--csv", "--duration", "80"};
  constexpr int kMonitorStarts = 3;
  std::unique_ptr<ChildProcess> csv;
  std::string earlier;  // the logs of the monitors that did not receive
  for (int start = 1;; ++start) {
    csv = std::make_unique<ChildProcess>(
        csv_args, (dir.path / (start == 1 ? "monitor.log" : "monitor-" + std::to_string(start) + ".log")).string());
    ASSERT_TRUE(csv->started());
    const bool last = start == kMonitorStarts;
    const auto wait = ve::test::patience(last ? 45s : 20s);
    if (wait_until([&] { return csv_rows(csv->log()) > 4000; }, wait)) break;
    const std::string log = csv->log();
    ASSERT_FALSE(last) << earlier << "monitor " << start << ":\n" << log << "\n" << encoder.log();
    std::printf("[ note     ] `monitor --csv` (start %d of %d) received %zu rows within %lld s (Fast DDS 2.9.1 race, "
                "top of dds_security_test.cpp); started once more. Its log had %s\n",
                start, kMonitorStarts, csv_rows(log), static_cast<long long>(wait.count() / 1000),
                log.find("Attempting to add existing reader") != std::string::npos
                    ? "\"Attempting to add existing reader\""
                    : "no \"Attempting to add existing reader\"");
    std::fflush(stdout);
    earlier += "monitor " + std::to_string(start) + ":\n" + log + "\n";
    csv.reset();
  }
  // A generous window more for the denied ones, while the permitted one keeps receiving.
  const std::uint64_t monitor_before = monitor.states_received();
  std::this_thread::sleep_for(5s);
  EXPECT_GT(monitor.states_received(), monitor_before + (ve::test::kRealTimeFigures ? 4000 : 0));

  std::printf("[ figures  ] state samples received: monitor %llu, `monitor --csv` %zu; unauthenticated %llu, "
              "intruder with forged permissions %llu; the intruder was admitted by %d, the forged one by %d "
              "participant(s) of other processes\n",
              static_cast<unsigned long long>(monitor.states_received()), csv_rows(csv->log()),
              static_cast<unsigned long long>(open.states_received()),
              static_cast<unsigned long long>(forged.states_received()), intruder.admitted_by_others(local),
              forged.admitted_by_others(local));
  EXPECT_GE(monitor.state_writers_matched(), 1);  // the encoder's state writers
  EXPECT_EQ(open.states_received(), 0u);
  EXPECT_EQ(open.state_writers_matched(), 0);
  EXPECT_EQ(forged.states_received(), 0u);
  EXPECT_EQ(forged.state_writers_matched(), 0);
  // Authenticated and admitted to the domain by the encoder (and the CSV monitor),
  // unlike the one with forged permissions.
  EXPECT_GE(intruder.admitted_by_others(local), 1);
  EXPECT_EQ(forged.admitted_by_others(local), 0);
  EXPECT_GE(monitor.admitted_by_others(local), 1);

  // The encoder ran with the secure profiles.
  EXPECT_NE(encoder.log().find("XML profiles from " + pki.profiles("encoder").string()), std::string::npos)
      << encoder.log();
  csv->signal(SIGINT);
  EXPECT_EQ(csv->wait_exit(ve::test::patience(20s)), 0) << csv->log();
  encoder.signal(SIGINT);
  EXPECT_EQ(encoder.wait_exit(ve::test::patience(20s)), 0) << encoder.log();
}

TEST(DdsSecurity, OnlyThePermittedMonitorStartsACalibration) {
  REQUIRE_PKI();
  const Pki& pki = Pki::get();
  TempDir dir;
  const fs::path encoder_machine = make_machine(dir.path, "encoder", pki.profiles("encoder"));
  const int domain = ve::test::dds_domain();
  constexpr std::uint64_t kOpenRequest = 601, kForgedRequest = 602, kMonitorRequest = 603, kAbortRequest = 604;

  ChildProcess encoder(run_args(encoder_machine, domain), (dir.path / "run.log").string());
  ASSERT_TRUE(encoder.started());

  // They join one at a time, each once the previous one is done with the encoder, the
  // permitted monitor first (the top of this file says why). Without security there is
  // no handshake.
  Peer open(domain, "unauthenticated", {});
  ASSERT_TRUE(open.ok());
  ASSERT_TRUE(open.write_commands());
  ASSERT_TRUE(open.read_status());
  // The permitted monitor: matched both ways with the encoder, discovery and
  // authentication are done.
  const std::unique_ptr<Peer> monitor_peer = join_once_more(
      "monitor",
      [&]() -> std::unique_ptr<Peer> {
        auto p = std::make_unique<Peer>(domain, "monitor", pki.properties("monitor"));
        if (!p->ok() || !p->write_commands() || !p->read_status()) {
          ADD_FAILURE() << "the monitor's participant, command writer or status reader was not created";
          return nullptr;
        }
        return p;
      },
      [&](Peer& p) {
        return p.command_readers_matched() > 0 && p.status_writers_matched() > 0 &&
               p.admitted_by_others({&p, &open}) > 0;
      },
      encoder);
  ASSERT_NE(monitor_peer, nullptr);
  // The encoder admits the intruder's participant (authentication and permissions pass)...
  const std::unique_ptr<Peer> intruder = join_once_more(
      "intruder",
      [&]() -> std::unique_ptr<Peer> {
        auto p = std::make_unique<Peer>(domain, "intruder", pki.properties("intruder"));
        if (!p->ok()) {
          ADD_FAILURE() << "the intruder has a valid identity and permissions: its participant is created";
          return nullptr;
        }
        // ...but its access control refuses it a writer of ve/calibration_command and a reader of the status.
        EXPECT_FALSE(p->write_commands());
        EXPECT_FALSE(p->read_status());
        return p;
      },
      [&](Peer& p) { return p.admitted_by_others({&p, &open, monitor_peer.get()}) > 0; }, encoder);
  ASSERT_NE(intruder, nullptr);
  // The one with forged permissions passes the handshake and is refused by the
  // encoder's access control: nothing of that is visible from this side, so it has the
  // time it takes to discover the encoder and a few handshake periods more.
  Peer forged(domain, "intruder-forged", pki.properties("intruder", true));
  ASSERT_TRUE(forged.ok());
  ASSERT_TRUE(forged.write_commands()) << "its forged permissions grant it ve/* locally";
  ASSERT_TRUE(forged.read_status());
  ASSERT_TRUE(wait_until([&] { return forged.discovered_others({&forged, &open, monitor_peer.get(), intruder.get()}) > 0; },
                         ve::test::patience(30s)))
      << forged.report() << "\n" << encoder.log();
  std::this_thread::sleep_for(3s);
  Peer& monitor = *monitor_peer;
  const std::vector<const Peer*> local{&open, intruder.get(), &forged, &monitor};
  std::printf("[ figures  ] joined: %s\n[ figures  ] joined: %s\n[ figures  ] joined: %s\n", intruder->report().c_str(),
              forged.report().c_str(), monitor.report().c_str());

  // The denied ones send first and get a generous window.
  ASSERT_TRUE(open.send(ve::dds::CALIBRATION_CMD_START, kOpenRequest, 0.002));
  ASSERT_TRUE(forged.send(ve::dds::CALIBRATION_CMD_START, kForgedRequest, 0.002));
  std::this_thread::sleep_for(5s);
  EXPECT_EQ(open.command_readers_matched(), 0);
  EXPECT_EQ(forged.command_readers_matched(), 0);
  EXPECT_EQ(open.status_writers_matched(), 0);
  EXPECT_EQ(forged.status_writers_matched(), 0);
  EXPECT_FALSE(monitor.any_status_of(kOpenRequest));
  EXPECT_FALSE(monitor.any_status_of(kForgedRequest));
  EXPECT_EQ(forged.admitted_by_others(local), 0);

  // The monitor's request starts a calibration: RUNNING, not "busy" with another one.
  ASSERT_TRUE(monitor.send(ve::dds::CALIBRATION_CMD_START, kMonitorRequest, 0.002));
  ve::dds::CalibrationStatus running;
  ASSERT_TRUE(wait_until([&] { return monitor.status_of(kMonitorRequest, ve::dds::CALIBRATION_STATE_RUNNING, running); },
                         20s))
      << encoder.log();
  EXPECT_EQ(running.axis_id(), kAxis);
  ASSERT_TRUE(monitor.send(ve::dds::CALIBRATION_CMD_ABORT, kAbortRequest));
  ve::dds::CalibrationStatus aborted;
  EXPECT_TRUE(wait_until(
      [&] { return monitor.status_of(kMonitorRequest, ve::dds::CALIBRATION_STATE_ABORTED, aborted); }, 20s))
      << encoder.log();

  // Nothing of the denied requests reached the encoder, nor its statuses them.
  EXPECT_FALSE(monitor.any_status_of(kOpenRequest));
  EXPECT_FALSE(monitor.any_status_of(kForgedRequest));
  EXPECT_TRUE(open.statuses().empty());
  EXPECT_TRUE(forged.statuses().empty());
  encoder.signal(SIGINT);
  EXPECT_EQ(encoder.wait_exit(20s), 0) << encoder.log();
  const std::string log = encoder.log();
  EXPECT_NE(log.find("calibration request " + std::to_string(kMonitorRequest) + " from monitor"), std::string::npos)
      << log;
  EXPECT_EQ(log.find("calibration request " + std::to_string(kOpenRequest)), std::string::npos) << log;
  EXPECT_EQ(log.find("calibration request " + std::to_string(kForgedRequest)), std::string::npos) << log;
  EXPECT_EQ(log.find("from unauthenticated"), std::string::npos) << log;
  EXPECT_EQ(log.find("from intruder"), std::string::npos) << log;
}

}  // namespace
