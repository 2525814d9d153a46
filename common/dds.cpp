#include "dds.h"

#include "cli.h"
#include "paths.h"
#include "removal_filter.h"
#include "shm_leftovers.h"
#include "trust.h"

#include <arpa/inet.h>
#include <fastdds/rtps/builtin/data/ParticipantProxyData.h>
#include <fastdds/rtps/participant/ParticipantDiscoveryInfo.h>
#include <fastdds/rtps/transport/shared_mem/SharedMemTransportDescriptor.h>
#include <fastdds/rtps/writer/WriterDiscoveryInfo.h>
#include <malloc.h>
#include <netinet/in.h>
#include <openssl/pem.h>
#include <openssl/x509.h>
#include <sys/socket.h>
#include <unistd.h>
#include <fastdds/dds/domain/DomainParticipantFactory.hpp>
#include <fastdds/dds/log/Log.hpp>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <random>
#include <utility>
#include <vector>

namespace farm::dds {

using eprosima::fastrtps::types::ReturnCode_t;

namespace {

bool file_exists(const std::string& p) { return std::ifstream(p).good(); }

// Whether a UDP port can be bound now (no process of this host listens on it).
bool udp_port_free(uint32_t port) {
  const int fd = ::socket(AF_INET, SOCK_DGRAM, 0);
  if (fd < 0) return true;  // cannot tell: Fast DDS finds out itself
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_ANY);
  a.sin_port = htons(static_cast<uint16_t>(port));
  const bool ok = ::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0;
  ::close(fd);
  return ok;
}

bool uses_shared_memory(const fdds::DomainParticipantQos& q) {
  if (q.transport().use_builtin_transports) return true;  // Fast DDS's builtin set has shared memory
  for (const auto& t : q.transport().user_transports)
    if (std::dynamic_pointer_cast<eprosima::fastdds::rtps::SharedMemTransportDescriptor>(t)) return true;
  return false;
}

// Fast DDS gives a new participant the lowest free participant id; after a SIGKILL that is the
// killed process's, and taking it over recreates that id's shared-memory port segments while a
// live peer may keep writing into the segments it had opened (Fast DDS 2.9): a learner resumed
// after a SIGKILL then never heard a worker that outlived the killed learner. A participant takes
// the lowest id whose unicast ports no process has left a segment for (/dev/shm/fastrtps_port<N>)
// and whose UDP ports are free; -1 (Fast DDS chooses) when none is left.
int participant_id_without_leftovers(int domain, const eprosima::fastrtps::rtps::PortParameters& p) {
  constexpr int kMaxId = 119;  // ports of id 120 would reach the next domain's range (gain 2, 250 per domain)
  for (int id = 0; id <= kMaxId; ++id) {
    const uint32_t base = p.portBase + p.domainIDGain * uint32_t(domain) + p.participantIDGain * uint32_t(id);
    const uint32_t ports[2] = {base + p.offsetd1, base + p.offsetd3};  // metatraffic and user unicast
    bool clean = true;
    for (uint32_t port : ports)
      clean =
          clean && port < 65536 && !file_exists("/dev/shm/fastrtps_port" + std::to_string(port)) && udp_port_free(port);
    if (clean) return id;
  }
  return -1;
}

// The profiles file a process uses when none is given: next to the binary's install prefix, then
// the source tree it was built from.
std::string default_profiles_file() {
  const std::string dir = executable_dir();
  if (!dir.empty()) {
    for (const char* rel : {"/../share/farm/fastdds_profiles.xml", "/fastdds_profiles.xml"}) {
      if (file_exists(dir + rel)) return dir + rel;
    }
  }
  return FARM_DEFAULT_PROFILES;
}

// DDS Security with the builtin plugins: PKI-DH authentication, signed permissions, AES-GCM.
void enable_security(std::string& dir, fdds::DomainParticipantQos& pqos) {
  namespace fs = std::filesystem;
  dir = fs::absolute(dir).lexically_normal().string();
  for (const char* f : {"ca.cert.pem", "cert.pem", "key.pem", "governance.p7s", "permissions.p7s"}) {
    if (!file_exists(dir + "/" + f))
      throw std::runtime_error("DDS Security: " + dir + "/" + f +
                               " is missing (make the folder with deploy/make-pki.sh)");
  }
  auto& props = pqos.properties().properties();
  auto set = [&](const std::string& k, const std::string& v) { props.emplace_back(k, v); };
  const std::string f = "file://" + dir + "/";
  set("dds.sec.auth.plugin", "builtin.PKI-DH");
  set("dds.sec.auth.builtin.PKI-DH.identity_ca", f + "ca.cert.pem");
  set("dds.sec.auth.builtin.PKI-DH.identity_certificate", f + "cert.pem");
  set("dds.sec.auth.builtin.PKI-DH.private_key", f + "key.pem");
  // A revocation list (deploy/make-pki.sh --revoke): Fast DDS refuses a revoked certificate, the
  // peer's in authentication and its own at the participant's creation. It reads the list only
  // then, and cannot create a participant with an expired list: said here, plainly, first.
  if (file_exists(dir + "/crl.pem")) {
    if (const std::string why = crl_problem(dir + "/crl.pem"); !why.empty())
      throw std::runtime_error("DDS Security: " + why);
    set("dds.sec.auth.builtin.PKI-DH.identity_crl", f + "crl.pem");
  }
  set("dds.sec.access.plugin", "builtin.Access-Permissions");
  set("dds.sec.access.builtin.Access-Permissions.permissions_ca", f + "ca.cert.pem");
  set("dds.sec.access.builtin.Access-Permissions.governance", f + "governance.p7s");
  set("dds.sec.access.builtin.Access-Permissions.permissions", f + "permissions.p7s");
  set("dds.sec.crypto.plugin", "builtin.AES-GCM-GMAC");
}

// Fast DDS 2.9.1's Discovery Server cannot carry DDS Security (deploy/discovery/peers_udp.xml says
// what was seen): a secured participant that is a client of one would wait forever for a farm it
// never meets, so it is refused with what to use instead.
void refuse_discovery_server_with_security(const fdds::DomainParticipantQos& pqos) {
  using eprosima::fastrtps::rtps::DiscoveryProtocol;
  std::string how;
  for (const char* var : {"ROS_DISCOVERY_SERVER", "FASTDDS_ENVIRONMENT_FILE"}) {
    const char* v = std::getenv(var);
    if (v && *v && how.empty()) how = std::string(var) + "=" + v + " is set";
  }
  const auto protocol = pqos.wire_protocol().builtin.discovery_config.discoveryProtocol;
  if (how.empty() && protocol != DiscoveryProtocol::SIMPLE && protocol != DiscoveryProtocol::NONE)
    how = "the profile's discovery is a Discovery Server's";
  if (how.empty()) return;
  throw std::runtime_error("DDS Security cannot run through a Discovery Server in Fast DDS 2.9.1 (" + how +
                           "): a secured farm discovers by multicast (discovery/simple.xml) or by unicast to its "
                           "hosts (discovery/peers_udp.xml), without ROS_DISCOVERY_SERVER; the Discovery Server is "
                           "for a trusted network, without --security");
}

}  // namespace

// Who the remote participants are, under DDS Security: whether authentication accepted each one,
// and the worker name each remote writer's partition gave it at its discovery (trust.h). The subject
// in a participant's identity token (dds.cert.sn) is kept for messages only: Fast DDS 2.9.1 never
// checks it against the authenticated certificate, so a participant may put any name there.
// Entries stay after a participant leaves (its last samples may still wait in a reader; under DDS
// Security a GUID prefix begins with a hash of the certificate's subject, so a participant with
// another certificate does not take it over) and are bounded: beyond kMaxIdentities, departed
// entries go first, then unauthenticated ones, oldest first.
class ParticipantIdentities : public fdds::DomainParticipantListener {
 public:
  static constexpr size_t kMaxIdentities = 4096;

  void on_participant_discovery(fdds::DomainParticipant*,
                                eprosima::fastrtps::rtps::ParticipantDiscoveryInfo&& info) override {
    using Info = eprosima::fastrtps::rtps::ParticipantDiscoveryInfo;
    const auto& prefix = info.info.m_guid.guidPrefix;
    std::lock_guard<std::mutex> lk(mu_);
    if (info.status == Info::REMOVED_PARTICIPANT || info.status == Info::DROPPED_PARTICIPANT) {
      auto it = ids_.find(prefix);
      if (it != ids_.end()) it->second.gone = true;
      return;
    }
    const std::string* sn =
        eprosima::fastrtps::rtps::DataHolderHelper::find_property_value(info.info.identity_token_, "dds.cert.sn");
    Entry* e = entry(prefix);
    if (e && !(e->authorized && !e->subject.empty())) e->subject = sn ? *sn : "";
  }

  void onParticipantAuthentication(fdds::DomainParticipant*,
                                   eprosima::fastrtps::rtps::ParticipantAuthenticationInfo&& info) override {
    using Info = eprosima::fastrtps::rtps::ParticipantAuthenticationInfo;
    std::lock_guard<std::mutex> lk(mu_);
    if (info.status != Info::AUTHORIZED_PARTICIPANT) {
      ids_.erase(info.guid.guidPrefix);
      return;
    }
    if (Entry* e = entry(info.guid.guidPrefix)) e->authorized = true;
  }

  // The CN its identity token claims (for messages only: nothing checks it).
  std::string token_name_of(const eprosima::fastrtps::rtps::GuidPrefix_t& prefix) const {
    std::lock_guard<std::mutex> lk(mu_);
    auto it = ids_.find(prefix);
    return it == ids_.end() ? "" : common_name_of_subject(it->second.subject);
  }

  // Fast DDS calls this before it matches the writer with a local reader, whatever the status mask.
  void on_publisher_discovery(fdds::DomainParticipant*, eprosima::fastrtps::rtps::WriterDiscoveryInfo&& info) override {
    using Info = eprosima::fastrtps::rtps::WriterDiscoveryInfo;
    if (!is_worker_topic(info.info.topicName().to_string())) return;
    const WriterNames::Event event = info.status == Info::DISCOVERED_WRITER    ? WriterNames::Event::kDiscovered
                                     : info.status == Info::CHANGED_QOS_WRITER ? WriterNames::Event::kChanged
                                                                               : WriterNames::Event::kRemoved;
    writers_.writer(info.info.guid(), info.info.m_qos.m_partition.getNames(), event);
  }

  std::string name_of(const eprosima::fastrtps::rtps::GUID_t& writer, std::string* why) const {
    {
      std::lock_guard<std::mutex> lk(mu_);
      auto it = ids_.find(writer.guidPrefix);
      if (it == ids_.end() || !it->second.authorized) {
        if (why) *why = "its participant is not authenticated";
        return "";
      }
    }
    return writers_.name_of(writer, why);
  }

 private:
  struct Entry {
    std::string subject;
    bool authorized = false, gone = false;
    uint64_t order = 0;
  };
  // The entry of prefix, made room for if new; nullptr when every entry is a live authenticated one.
  Entry* entry(const eprosima::fastrtps::rtps::GuidPrefix_t& prefix) {
    auto it = ids_.find(prefix);
    if (it != ids_.end()) return &it->second;
    if (ids_.size() >= kMaxIdentities) {
      auto victim = ids_.end();
      for (auto j = ids_.begin(); j != ids_.end(); ++j) {
        const auto rank = [](const Entry& x) { return x.gone ? 0 : (x.authorized ? 2 : 1); };
        if (rank(j->second) == 2) continue;
        if (victim == ids_.end() || rank(j->second) < rank(victim->second) ||
            (rank(j->second) == rank(victim->second) && j->second.order < victim->second.order))
          victim = j;
      }
      if (victim == ids_.end()) return nullptr;
      ids_.erase(victim);
    }
    Entry& e = ids_[prefix];
    e.order = next_order_++;
    return &e;
  }

  mutable std::mutex mu_;
  std::map<eprosima::fastrtps::rtps::GuidPrefix_t, Entry> ids_;
  uint64_t next_order_ = 0;
  WriterNames writers_;
};

namespace {
std::atomic<bool> g_reload_grants{false};
}  // namespace

void request_grants_reload() { g_reload_grants.store(true); }

bool is_worker_topic(const std::string& topic_name) {
  return topic_name == kBatchTopic || topic_name == kWorkerStatusTopic || topic_name == kEvalAnswerTopic;
}

std::string security_dir_of(const BusOptions& opts) {
  if (!opts.security_dir.empty()) return opts.security_dir;
  const char* env = std::getenv("FARM_SECURITY_DIR");
  return env ? env : "";
}

std::string certificate_name(const std::string& security_dir) {
  const std::string path = security_dir + "/cert.pem";
  FILE* f = std::fopen(path.c_str(), "r");
  if (!f)
    throw std::runtime_error("DDS Security: cannot read " + path + ": " + std::strerror(errno) +
                             " (make the folder with deploy/make-pki.sh)");
  X509* cert = PEM_read_X509(f, nullptr, nullptr, nullptr);
  std::fclose(f);
  if (!cert) throw std::runtime_error("DDS Security: " + path + " holds no PEM certificate");
  // The subject in the form Fast DDS puts in the identity token, so both ends read the same name.
  char* text = X509_NAME_oneline(X509_get_subject_name(cert), nullptr, 0);
  const std::string subject = text ? text : "";
  OPENSSL_free(text);
  X509_free(cert);
  const std::string name = common_name_of_subject(subject);
  if (name.empty())
    throw std::runtime_error("DDS Security: the subject of " + path + " (" + subject +
                             ") has no single common name (CN); a farm certificate's CN is its participant's name");
  return name;
}

std::string common_name_of_subject(const std::string& subject) {
  std::vector<std::pair<std::string, std::string>> attributes;  // (type, value), in order
  auto is_type_char = [](char c) { return std::isalnum(static_cast<unsigned char>(c)) || c == '.'; };
  if (!subject.empty() && subject[0] == '/') {
    // OpenSSL's one-line form, as Fast DDS 2.9's identity token carries it: "/O=rollout-farm/CN=w1".
    // A '/' starts the next attribute when a type and '=' follow it.
    for (size_t i = 0; i < subject.size(); ++i) {
      if (subject[i] == '/') {
        size_t j = i + 1;
        while (j < subject.size() && is_type_char(subject[j])) ++j;
        if (j > i + 1 && j < subject.size() && subject[j] == '=') {
          attributes.emplace_back(subject.substr(i + 1, j - i - 1), "");
          i = j;
          continue;
        }
      }
      if (attributes.empty()) return "";
      attributes.back().second += subject[i];
    }
  } else {
    // RFC 2253: "CN=w1,O=rollout-farm"; ',' or '+' separate attributes, a backslash escapes a character or
    // gives two hex digits.
    std::string type, value;
    bool in_value = false;
    auto end_attribute = [&] {
      if (in_value) attributes.emplace_back(type, value);
      type.clear();
      value.clear();
      in_value = false;
    };
    for (size_t i = 0; i < subject.size(); ++i) {
      const char c = subject[i];
      if (!in_value) {
        if (c == '=')
          in_value = true;
        else if (c != ' ')
          type += c;
      } else if (c == '\\' && i + 2 < subject.size() && std::isxdigit(static_cast<unsigned char>(subject[i + 1])) &&
                 std::isxdigit(static_cast<unsigned char>(subject[i + 2]))) {
        value += static_cast<char>(std::stoi(subject.substr(i + 1, 2), nullptr, 16));
        i += 2;
      } else if (c == '\\' && i + 1 < subject.size()) {
        value += subject[++i];
      } else if (c == ',' || c == '+') {
        end_attribute();
      } else {
        value += c;
      }
    }
    end_attribute();
  }
  std::string cn;
  int found = 0;
  for (const auto& [type, value] : attributes) {
    if (type == "CN") {
      cn = value;
      ++found;
    }
  }
  return found == 1 ? cn : "";
}

std::string Bus::authenticated_name(const eprosima::fastrtps::rtps::GUID_t& writer, std::string* why) const {
  if (!identities_) {
    if (why) *why = "DDS Security is off";
    return "";
  }
  const std::string name = identities_->name_of(writer, why);
  if (name.empty()) return "";
  std::lock_guard<std::mutex> lk(grants_mu_);
  if (!grants_.count(name)) {
    if (why) *why = "'" + name + "' is not granted by the permissions this learner read last: revoked or never named";
    return "";
  }
  return name;
}

std::string Bus::token_name(const eprosima::fastrtps::rtps::GUID_t& writer) const {
  return identities_ ? identities_->token_name_of(writer.guidPrefix) : "";
}

std::set<std::string> Bus::granted_workers() const {
  std::lock_guard<std::mutex> lk(grants_mu_);
  return grants_;
}

std::string Bus::reload_grants_if_requested() {
  if (security_dir_.empty() || !g_reload_grants.exchange(false)) return "";
  std::set<std::string> fresh;
  const std::string error =
      load_worker_grants(security_dir_ + "/permissions.p7s", security_dir_ + "/ca.cert.pem", fresh);
  std::lock_guard<std::mutex> lk(grants_mu_);
  if (!error.empty()) return "worker grants not reloaded, the previous ones stay: " + error;
  std::string added, dropped;
  for (const auto& n : fresh)
    if (!grants_.count(n)) added += (added.empty() ? "" : " ") + n;
  for (const auto& n : grants_)
    if (!fresh.count(n)) dropped += (dropped.empty() ? "" : " ") + n;
  grants_.swap(fresh);
  return "worker grants reloaded from " + security_dir_ + "/permissions.p7s: dropped " +
         (dropped.empty() ? "none" : dropped) + "; added " + (added.empty() ? "none" : added) + "; " +
         std::to_string(grants_.size()) + " granted";
}

fdds::DataWriterQos Bus::writer_qos(const std::string& topic_name, const std::string& profile) {
  fdds::DataWriterQos qos;
  if (publisher_->get_datawriter_qos_from_profile(profile, qos) != ReturnCode_t::RETCODE_OK)
    throw std::runtime_error("no DDS writer profile '" + profile + "' in " + profiles_file_);
  if (!security_dir_.empty() && is_worker_topic(topic_name))
    qos.properties().properties().emplace_back("partitions", worker_partition(own_name_));
  return qos;
}

fdds::DataReaderQos Bus::reader_qos(const std::string& topic_name, const std::string& profile) {
  fdds::DataReaderQos qos;
  if (subscriber_->get_datareader_qos_from_profile(profile, qos) != ReturnCode_t::RETCODE_OK)
    throw std::runtime_error("no DDS reader profile '" + profile + "' in " + profiles_file_);
  if (!security_dir_.empty() && is_worker_topic(topic_name))
    qos.properties().properties().emplace_back("partitions", worker_partition("*"));
  return qos;
}

void add_bus_options(CLI::App& app, BusOptions& opts) {
  app.add_option("--domain", opts.domain, "DDS domain of the farm")->check(CLI::Range(0, 232))->capture_default_str();
  app.add_option("--dds-profiles", opts.profiles_file,
                 "Fast DDS XML profiles (default: FASTRTPS_DEFAULT_PROFILES_FILE, else fastdds_profiles.xml next "
                 "to the program or in deploy/)");
  app.add_option("--security", opts.security_dir,
                 "DDS Security folder made by deploy/make-pki.sh (default: FARM_SECURITY_DIR, else none)");
}

Bus::Bus(const BusOptions& opts, const std::string& participant_name) : domain_(opts.domain) {
  auto* factory = fdds::DomainParticipantFactory::get_instance();
  const char* env_value = std::getenv("FASTRTPS_DEFAULT_PROFILES_FILE");
  const std::string env = env_value ? env_value : "";
  const char* from = "the default";
  if (!opts.profiles_file.empty()) {
    profiles_file_ = opts.profiles_file;
    from = "--dds-profiles";
  } else if (!env.empty()) {
    profiles_file_ = env;
    from = "FASTRTPS_DEFAULT_PROFILES_FILE";
  } else {
    profiles_file_ = default_profiles_file();
  }
  if (!file_exists(profiles_file_)) {
    throw std::runtime_error(std::string("DDS profiles file not found: ") + profiles_file_ + " (from " + from + ")");
  }
  if (!env.empty()) {
    std::error_code ec;
    if (std::filesystem::equivalent(env, profiles_file_, ec)) {
      profiles_file_ = env;  // the name Fast DDS loads it under, so it is parsed once
    } else {
      // Fast DDS would load the variable's file by itself as well, and refuse the flag's file for
      // defining the same profiles again: the flag wins, for this process and its children.
      std::fprintf(stderr, "--dds-profiles %s overrides FASTRTPS_DEFAULT_PROFILES_FILE=%s\n", profiles_file_.c_str(),
                   env.c_str());
      unsetenv("FASTRTPS_DEFAULT_PROFILES_FILE");
    }
  }
  // The file the standard variable names is loaded by the factory on its first participant, which
  // is too late for the profile lookups below: load it now (once; a file already parsed is not
  // parsed again), then the file in effect.
  factory->load_profiles();
  if (factory->load_XML_profiles_file(profiles_file_) != ReturnCode_t::RETCODE_OK) {
    throw std::runtime_error("cannot load DDS profiles from " + profiles_file_ + " (from " + from +
                             "; see Fast DDS's XML parser messages above)");
  }
  fdds::DomainParticipantQos pqos;
  if (factory->get_participant_qos_from_profile("farm_participant", pqos) != ReturnCode_t::RETCODE_OK) {
    throw std::runtime_error("profile 'farm_participant' missing in " + profiles_file_);
  }
  pqos.name(participant_name);
  if (uses_shared_memory(pqos)) {
    // The data segments killed processes left in /dev/shm go first; the memory is the host's (a tmpfs).
    const ShmLeftovers gone = remove_dead_segments();
    if (gone.segments > 0)
      std::fprintf(stderr, "removed %d shared-memory segment(s) of ended Fast DDS processes from /dev/shm (%.1f MiB)\n",
                   gone.segments, double(gone.bytes) / (1024.0 * 1024.0));
    // A participant id given in the profiles file is the operator's; otherwise one whose ports no
    // killed process left behind. Only with shared memory: the leftovers are its segments, and a
    // UDP-only profile may discover by well-known ports (peers_udp.xml: the first four participant
    // ids of the learner's host).
    if (pqos.wire_protocol().participant_id < 0)
      pqos.wire_protocol().participant_id = participant_id_without_leftovers(opts.domain, pqos.wire_protocol().port);
  }
  participant_id_ = pqos.wire_protocol().participant_id;
  filter_participant_removals(pqos);
  security_dir_ = security_dir_of(opts);
  if (!security_dir_.empty()) {
    refuse_discovery_server_with_security(pqos);
    enable_security(security_dir_, pqos);
    own_name_ = certificate_name(security_dir_);
    identities_ = std::make_unique<ParticipantIdentities>();
  }
  // The listener hears participant discovery and authentication only (no entity status).
  participant_ = factory->create_participant(opts.domain, pqos, identities_.get(), fdds::StatusMask::none());
  if (!participant_) {
    throw std::runtime_error("cannot create DDS participant on domain " + std::to_string(opts.domain) +
                             (security_dir_.empty()
                                  ? std::string()
                                  : " with DDS Security from " + security_dir_ +
                                        " (certificate, key or signed documents rejected; see messages above)"));
  }
  // The worker names granted, from the permissions Fast DDS has just accepted (so its own message
  // comes first for a file it refuses, e.g. on a host whose clock is behind the CA's start).
  if (!security_dir_.empty()) {
    if (const std::string error =
            load_worker_grants(security_dir_ + "/permissions.p7s", security_dir_ + "/ca.cert.pem", grants_);
        !error.empty()) {
      factory->delete_participant(participant_);
      participant_ = nullptr;
      throw std::runtime_error("DDS Security: " + error);
    }
  }
  publisher_ = participant_->create_publisher(fdds::PUBLISHER_QOS_DEFAULT);
  subscriber_ = participant_->create_subscriber(fdds::SUBSCRIBER_QOS_DEFAULT);
  if (!publisher_ || !subscriber_) throw std::runtime_error("cannot create DDS publisher/subscriber");
}

Bus::~Bus() {
  if (participant_) {
    participant_->delete_contained_entities();
    fdds::DomainParticipantFactory::get_instance()->delete_participant(participant_);
  }
}

fdds::Topic* Bus::topic(const std::string& name, fdds::TypeSupport type) {
  auto it = topics_.find(name);
  if (it != topics_.end()) return it->second;
  type.register_type(participant_);
  fdds::Topic* t = participant_->create_topic(name, type.get_type_name(), fdds::TOPIC_QOS_DEFAULT);
  if (!t) throw std::runtime_error("cannot create DDS topic " + name);
  topics_[name] = t;
  return t;
}

namespace {

std::mutex g_refused_mu;
std::map<uint64_t, uint64_t> g_refused_by_bound;  // the history's payload size -> samples refused

// The error ReaderHistory::can_change_be_added_nts logs for a sample over the history's payload
// size: "Change payload size of 'N' bytes is larger than the history payload size of 'B' bytes and
// cannot be resized." B is the refusing reader's bound, which tells its readers apart.
class RefusedForSizeCounter : public eprosima::fastdds::dds::LogConsumer {
 public:
  void Consume(const eprosima::fastdds::dds::Log::Entry& e) override {
    static const std::string kSays = "is larger than the history payload size of '";
    if (e.kind != eprosima::fastdds::dds::Log::Kind::Error || e.context.category == nullptr ||
        std::strcmp(e.context.category, "RTPS_READER_HISTORY") != 0)
      return;
    const size_t at = e.message.find(kSays);
    if (at == std::string::npos) return;
    const uint64_t bound = std::strtoull(e.message.c_str() + at + kSays.size(), nullptr, 10);
    std::lock_guard<std::mutex> lk(g_refused_mu);
    ++g_refused_by_bound[bound];
  }
};

}  // namespace

void count_samples_refused_for_size() {
  static std::once_flag once;
  std::call_once(once,
                 [] { eprosima::fastdds::dds::Log::RegisterConsumer(std::make_unique<RefusedForSizeCounter>()); });
}

uint64_t samples_refused_for_size(uint32_t bound) {
  // The history's payload size is the type's maximum plus an allowance for alignment (3 bytes in
  // Fast DDS 2.9): the counts of the few sizes just above the bound are its reader's.
  std::lock_guard<std::mutex> lk(g_refused_mu);
  uint64_t n = 0;
  for (auto it = g_refused_by_bound.lower_bound(bound); it != g_refused_by_bound.end() && it->first < bound + 8ull;
       ++it)
    n += it->second;
  return n;
}

void with_mapped_allocations(size_t bytes, const std::function<void()>& make) {
  constexpr size_t kMin = 128 << 10, kMax = 32 << 20;
  mallopt(M_MMAP_THRESHOLD, int(std::clamp(bytes, kMin, kMax)));
  try {
    make();
  } catch (...) {
    mallopt(M_MMAP_THRESHOLD, int(kMax));
    mallopt(M_TRIM_THRESHOLD, int(2 * kMax));
    throw;
  }
  mallopt(M_MMAP_THRESHOLD, int(kMax));
  mallopt(M_TRIM_THRESHOLD, int(2 * kMax));
}

void to_wire(const PolicyParams& p, const std::string& experiment_id, farm::msg::PolicyWeights& w) {
  w.experiment_id(experiment_id);
  w.version(p.version);
  w.head(static_cast<int32_t>(p.head));
  w.layer_sizes(std::vector<int32_t>(p.layout.sizes.begin(), p.layout.sizes.end()));
  w.activation(static_cast<int32_t>(p.layout.activation));
  w.log_std_min(p.log_std_min);
  w.log_std_max(p.log_std_max);
  w.obs_mean(p.obs_mean);
  w.obs_std(p.obs_std);
  w.parameters(p.params);
  w.epsilon(p.epsilon);
  w.log_std(p.log_std);
}

PolicyParams from_wire(const farm::msg::PolicyWeights& w) {
  PolicyParams p;
  p.version = w.version();
  if (w.head() != static_cast<int32_t>(PolicyHead::kSquashedGaussian) &&
      w.head() != static_cast<int32_t>(PolicyHead::kDiscreteQ) &&
      w.head() != static_cast<int32_t>(PolicyHead::kGaussian))
    throw std::invalid_argument("PolicyWeights: unknown policy head " + std::to_string(w.head()));
  p.head = static_cast<PolicyHead>(w.head());
  if (!activation_known(w.activation()))
    throw std::invalid_argument("PolicyWeights: unknown activation " + std::to_string(w.activation()) +
                                " (expected 0 relu, 1 tanh or 2 elu)");
  p.layout.activation = static_cast<Activation>(w.activation());
  p.layout.sizes.assign(w.layer_sizes().begin(), w.layer_sizes().end());
  p.log_std_min = w.log_std_min();
  p.log_std_max = w.log_std_max();
  p.obs_mean = w.obs_mean();
  p.obs_std = w.obs_std();
  p.params = w.parameters();
  p.epsilon = w.epsilon();
  p.log_std = w.log_std();
  return p;
}

std::string hostname() {
  char buf[256] = {0};
  if (gethostname(buf, sizeof(buf) - 1) != 0) return "unknown";
  return buf;
}

uint64_t random_session_id() {
  std::random_device rd;
  return (static_cast<uint64_t>(rd()) << 32) ^ rd() ^
         static_cast<uint64_t>(std::chrono::steady_clock::now().time_since_epoch().count());
}

}  // namespace farm::dds
