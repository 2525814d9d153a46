// The farm's DDS plumbing: one participant per process, typed writers and readers whose QoS
// comes from named profiles in deploy/fastdds_profiles.xml. Only ingest, the weight publisher
// and the process mains use this; the learning code never sees DDS.
#pragma once

#include <fastdds/dds/domain/DomainParticipant.hpp>
#include <fastdds/dds/domain/DomainParticipantListener.hpp>
#include <fastdds/dds/publisher/DataWriter.hpp>
#include <fastdds/dds/publisher/Publisher.hpp>
#include <fastdds/dds/subscriber/DataReader.hpp>
#include <fastdds/dds/subscriber/DataReaderListener.hpp>
#include <fastdds/dds/subscriber/SampleInfo.hpp>
#include <fastdds/dds/subscriber/Subscriber.hpp>
#include <fastdds/dds/topic/Topic.hpp>
#include <fastdds/dds/topic/TypeSupport.hpp>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <stdexcept>
#include <string>

#include "farmPubSubTypes.h"
#include "mlp.h"
#include "wire_check.h"

namespace CLI {
class App;
}

namespace farm::dds {

namespace fdds = eprosima::fastdds::dds;

inline constexpr const char* kSpecTopic = "farm/ExperimentSpec";
// The learner writes its ExperimentSpec again this often while it runs. The topic is durable
// (TRANSIENT_LOCAL), but a worker that joined a busy farm was seen to wait 30 s without the stored
// sample while its own heartbeats reached the learner; a fresh write reaches every matched reader.
inline constexpr double kSpecRepublishSeconds = 2.0;
// A learner that wrote no weights for this long writes its latest again (same version, same batch
// quota: a worker that has them changes nothing). A worker that joined after another participant's
// weights displaced the learner's from its reader or intake gets them then, rather than waiting
// for a version that, with no worker's batches, never comes.
inline constexpr double kWeightsRepublishSeconds = 5.0;
inline constexpr const char* kBatchTopic = "farm/TransitionBatch";
inline constexpr const char* kWeightsTopic = "farm/PolicyWeights";
inline constexpr const char* kWorkerStatusTopic = "farm/WorkerStatus";
inline constexpr const char* kLearnerStatsTopic = "farm/LearnerStats";
// Evaluations asked of one worker and answered by it (farm.idl); both use the batch profiles.
inline constexpr const char* kEvalRequestTopic = "farm/EvaluationRequest";
inline constexpr const char* kEvalAnswerTopic = "farm/EvaluationAnswer";
// The longest worker id and error text an EvaluationAnswer may carry (a worker cuts its error text).
inline constexpr size_t kMaxEvalTextBytes = 1024;
// What a worker's readers take at most, serialized, before knowing any experiment: an
// ExperimentSpec (a config and a model of at most 64 MiB of files, robots/terms/mjcf_bundle.h),
// PolicyWeights, and an EvaluationRequest (a policy and a few ids). Larger samples are refused
// before memory is taken for them (Reader's bounded constructor); the learner refuses to start
// an experiment whose spec or policy would not fit (learner/farm_service.cpp).
inline constexpr uint32_t kMaxSpecBytes = 72u << 20;
inline constexpr uint32_t kMaxPolicyBytes = 64u << 20;
inline constexpr uint32_t kMaxEvalRequestBytes = kMaxPolicyBytes + (64u << 10);
// What the learner's heartbeat reader takes at most, serialized: a worker's ids, host and state, and
// its last error, which it cuts to kMaxStatusErrorBytes.
inline constexpr uint32_t kMaxStatusBytes = 64u << 10;
inline constexpr size_t kMaxStatusErrorBytes = 4096;

struct BusOptions {
  int domain = 0;
  // Empty: FASTRTPS_DEFAULT_PROFILES_FILE if set, else fastdds_profiles.xml next to the program
  // (or in ../share/farm), else the one in deploy/. A file given here wins over the variable.
  std::string profiles_file;
  // DDS Security: a folder made by deploy/make-pki.sh (ca.cert.pem, cert.pem, key.pem,
  // governance.p7s, permissions.p7s, and crl.pem once a certificate was revoked). Empty:
  // FARM_SECURITY_DIR if set, else no security.
  std::string security_dir;
};

// Adds --domain D (0..232), --dds-profiles FILE and --security DIR to a main's options (cli.h),
// read into opts.
void add_bus_options(CLI::App& app, BusOptions& opts);

// The DDS Security folder these options select (--security, else FARM_SECURITY_DIR), "" for none.
std::string security_dir_of(const BusOptions& opts);

// A participant's name under DDS Security is the common name (CN) of its certificate's subject:
// deploy/make-pki.sh makes "CN=<name>,O=rollout-farm", and a worker's id is that name.
// certificate_name reads DIR/cert.pem; it throws std::runtime_error naming the file when it is
// missing, not a certificate, or has no single CN.
std::string certificate_name(const std::string& security_dir);
// The CN of a certificate subject in the text of a Fast DDS identity token (dds.cert.sn): OpenSSL's
// one-line form in Fast DDS 2.9 ("/O=rollout-farm/CN=w1"), or RFC 2253 ("CN=w1,O=rollout-farm",
// escapes undone). "" when it has no CN or more than one.
std::string common_name_of_subject(const std::string& subject);

class ParticipantIdentities;

// Under DDS Security the topics a worker writes (batches, heartbeats, evaluation answers) go in
// the worker's own partition, worker/<certificate name>, which its signed permissions alone allow
// it (trust.h); their readers read worker/*. Other topics stay in the default partition.
bool is_worker_topic(const std::string& topic_name);

// Asks every Bus of this process to read its permissions document again at its next
// reload_grants_if_requested (async-signal-safe: a SIGHUP handler calls it).
void request_grants_reload();

class Bus {
 public:
  Bus(const BusOptions& opts, const std::string& participant_name);
  ~Bus();
  Bus(const Bus&) = delete;
  Bus& operator=(const Bus&) = delete;

  fdds::DomainParticipant* participant() { return participant_; }
  fdds::Publisher* publisher() { return publisher_; }
  fdds::Subscriber* subscriber() { return subscriber_; }
  int domain() const { return domain_; }
  const std::string& profiles_file() const { return profiles_file_; }
  // The DDS participant id asked for (its unicast ports follow from it; Fast DDS moves on to the
  // next free ports when another process took them first); -1 when Fast DDS chose.
  int participant_id() const { return participant_id_; }
  // For start lines: "asked for participant id N", or that Fast DDS chose.
  std::string participant_label() const {
    return participant_id_ >= 0 ? "asked for participant id " + std::to_string(participant_id_)
                                : std::string("participant id chosen by Fast DDS");
  }
  // The DDS Security folder in use, or "" when security is off.
  const std::string& security_dir() const { return security_dir_; }
  // With DDS Security: the worker name of the writer of a sample
  // (SampleInfo::sample_identity.writer_guid()): the NAME of the one partition worker/NAME the writer
  // was in when it was discovered, which access control allowed only to a participant authenticated
  // with NAME's certificate (trust.h). "" with *why when the writer's participant is not
  // authenticated, the writer is unknown, in no worker partition, changed partitions after it was
  // discovered, or NAME is not granted by the permissions this process read last (a revoked worker).
  // The participant's identity token (dds.cert.sn) is never used: Fast DDS 2.9.1 does not check it
  // against the certificate. Always "" without security.
  std::string authenticated_name(const eprosima::fastrtps::rtps::GUID_t& writer, std::string* why = nullptr) const;
  // The CN the identity token of a writer's participant claims, for messages only ("" if none).
  std::string token_name(const eprosima::fastrtps::rtps::GUID_t& writer) const;
  // With DDS Security, after request_grants_reload(): reads DIR/permissions.p7s again, checked against
  // the permissions CA, and from then on refuses the worker names it no longer grants. Returns what
  // changed ("worker grants reloaded: dropped w2; added none; 3 granted"), or why the file was refused
  // (the previous grants stay); "" when no reload was asked or security is off.
  std::string reload_grants_if_requested();
  // The worker names the permissions grant, as read last (security only).
  std::set<std::string> granted_workers() const;
  // Fills a writer's or reader's QoS from a profile, plus this process's partition for a worker topic
  // under DDS Security; throws std::runtime_error naming the profile when it is missing.
  fdds::DataWriterQos writer_qos(const std::string& topic_name, const std::string& profile);
  fdds::DataReaderQos reader_qos(const std::string& topic_name, const std::string& profile);
  // Registers the type once and returns the topic (one per name per participant).
  fdds::Topic* topic(const std::string& name, fdds::TypeSupport type);

 private:
  std::unique_ptr<ParticipantIdentities> identities_;  // outlives participant_
  fdds::DomainParticipant* participant_ = nullptr;
  fdds::Publisher* publisher_ = nullptr;
  fdds::Subscriber* subscriber_ = nullptr;
  std::map<std::string, fdds::Topic*> topics_;
  std::string profiles_file_;
  std::string security_dir_;
  std::string own_name_;  // the certificate's name, under DDS Security
  mutable std::mutex grants_mu_;
  std::set<std::string> grants_;
  int domain_ = 0;
  int participant_id_ = -1;
};

// Samples of the IDL type type_name that this process's readers refused as malformed (CheckedType),
// and the reason for the last of them.
uint64_t samples_malformed(const std::string& type_name);
std::string last_malformed(const std::string& type_name);
// Books a malformed sample of type_name: counted, said on stderr for the first few of each type, and
// marked for the take in progress on this thread (take_malformed_mark).
void note_malformed(const std::string& type_name, const std::string& why);
// Whether the last sample decoded on this thread was malformed; clears the mark.
bool take_malformed_mark();

// A generated type whose decoding cannot end the process: the serialized sample is first walked
// against the type's wire layout (wire_check.h), so that a boolean byte out of range, a count past
// the payload or truncated data is refused before anything is allocated for it, and whatever the
// decoder still throws is caught. What Fast DDS does with a false deserialize differs between 2.9
// releases: some hand the sample on as valid; 2.9.1 (seen in integration.malformed) goes on to
// decode the next sample in the same take. So each decoding marks whether it refused (take_malformed_mark), and
// Reader::take_from skips a sample only when the last decoding of its take refused.
template <class T, class PubSubType>
class CheckedType : public PubSubType {
 public:
  CheckedType() : layout_(wire::layout_of(this->getName())) {
    if (!layout_) throw std::logic_error(std::string("no wire layout for DDS type ") + this->getName());
  }
  bool deserialize(eprosima::fastrtps::rtps::SerializedPayload_t* payload, void* data) override {
    std::string why = wire::walk(*layout_, payload->data, payload->length).text();
    if (why.empty()) {
      try {
        if (PubSubType::deserialize(payload, data)) {
          // The mark is the last decoding's: Fast DDS 2.9.1 goes on after a failed deserialize
          // and decodes the next sample within the same take, which must then be returned.
          take_malformed_mark();
          return true;
        }
        why = "the decoder refused it";
      } catch (const std::exception& e) {
        why = std::string("the decoder failed: ") + e.what();
      } catch (...) {
        why = "the decoder failed";
      }
    }
    *static_cast<T*>(data) = T();
    note_malformed(this->getName(), why);
    return false;
  }

 private:
  const wire::Layout* layout_;
};

template <class T, class PubSubType>
class Writer {
 public:
  Writer(Bus& bus, const std::string& topic_name, const std::string& profile) : bus_(bus) {
    fdds::Topic* t = bus.topic(topic_name, fdds::TypeSupport(new CheckedType<T, PubSubType>()));
    writer_ = bus.publisher()->create_datawriter(t, bus.writer_qos(topic_name, profile));
    if (!writer_) {
      throw std::runtime_error("cannot create DDS writer for " + topic_name + " with profile '" + profile +
                               "' (is it in " + bus.profiles_file() + "?)");
    }
  }
  ~Writer() { bus_.publisher()->delete_datawriter(writer_); }
  // Blocks up to the profile's max_blocking_time when the reliable history is full; returns
  // false then, and the caller retries: a batch is never dropped on the writer side.
  bool write(T& sample) { return writer_->write(&sample); }
  int matched() const {
    fdds::PublicationMatchedStatus st;
    writer_->get_publication_matched_status(st);
    return st.current_count;
  }
  bool wait_for_acks(double seconds) {
    return writer_->wait_for_acknowledgments(eprosima::fastrtps::Duration_t(seconds)) ==
           eprosima::fastrtps::types::ReturnCode_t::RETCODE_OK;
  }

 private:
  Bus& bus_;
  fdds::DataWriter* writer_ = nullptr;
};

// A generated type with a maximum serialized size of max_bytes. fastddsgen gives a type with
// unbounded sequences a nominal maximum (100 elements each) that a reader's history only grows from:
// under PREALLOCATED_WITH_REALLOC every sample gets what it claims to need, however large.
template <class T, class PubSubType>
class BoundedType : public CheckedType<T, PubSubType> {
 public:
  explicit BoundedType(uint32_t max_bytes) { this->m_typeSize = max_bytes; }
};

// Samples the readers of this process with the bound `bound` refused because they were larger
// than it (only readers with PREALLOCATED_MEMORY_MODE check; of the farm's, only a bounded Reader
// has it). Fast DDS 2.9 reports these refusals only in its log (category RTPS_READER_HISTORY, once
// per sample, naming the bound: the sample is marked irrelevant and never sent again), so
// count_samples_refused_for_size() adds a consumer to that log, once per process, that counts them
// by bound; the default consumer still prints them. Readers of one process are told apart by
// their bounds, so where a process counts them, no two of its bounds are within 8 bytes.
// A Fast DDS built without error logs (LOG_NO_ERROR) or a log filter that drops that category
// leaves the count at 0: the samples are refused all the same.
void count_samples_refused_for_size();
uint64_t samples_refused_for_size(uint32_t bound);

// Runs make() with glibc's mmap threshold at bytes (within 128 KiB..32 MiB), so that every
// allocation of at least that size made meanwhile is a mapping of its own, whose untouched pages
// take no memory and cost no clearing. Afterwards the threshold is left at 32 MiB and the trim
// threshold at 64 MiB, the values glibc's own adjustment settles on in a long-running process.
// Fast DDS's payload pool calloc()s each payload at the reader's bound: served from a heap (as
// glibc's raised threshold would do once the process has freed a large block), that calloc clears
// the whole bound, on the thread that receives, under the reader's lock.
void with_mapped_allocations(size_t bytes, const std::function<void()>& make);

template <class T, class PubSubType>
class Reader : public fdds::DataReaderListener {
 public:
  // on_data, if given, runs on Fast DDS's listener thread whenever samples arrive, with the DDS
  // reader to take them from (take_from), independently of the thread that owns this Reader.
  using OnData = std::function<void(fdds::DataReader*)>;
  Reader(Bus& bus, const std::string& topic_name, const std::string& profile, OnData on_data = {})
      : bus_(bus), on_data_(std::move(on_data)) {
    fdds::Topic* t = bus.topic(topic_name, fdds::TypeSupport(new CheckedType<T, PubSubType>()));
    type_name_ = t->get_type_name();
    reader_ = bus.subscriber()->create_datareader(t, bus.reader_qos(topic_name, profile), this);
    if (!reader_) {
      throw std::runtime_error("cannot create DDS reader for " + topic_name + " with profile '" + profile +
                               "' (is it in " + bus.profiles_file() + "?)");
    }
  }
  // A reader that takes no sample larger than max_sample_bytes serialized (encapsulation included).
  // The bound becomes the type's maximum size and the history PREALLOCATED_MEMORY_MODE, whatever
  // the profile says: that is the one memory policy under which Fast DDS 2.9 compares a sample's
  // announced size with the maximum when its first fragment arrives
  // (ReaderHistory::can_change_be_added_nts), and refuses it there, before a payload is reserved
  // for it, marking it irrelevant so the writer does not send it again. Each preallocated payload
  // is calloc'ed at the bound, so only the bytes a sample fills become resident. Fast DDS tells no
  // listener of such a refusal (neither sample lost nor sample rejected fires); it logs one error
  // per sample, which refused() counts (samples_refused_for_size). The topic must not have been
  // created on this bus with another type size.
  //
  // preallocate: the history's whole pool (max_samples payloads of the bound) is made here, each a
  // mapping of its own (with_mapped_allocations), so that the thread that receives never
  // allocates. Without it the pool grows on that thread, one payload at a time, as samples pile up,
  // and nothing else reaches the participant meanwhile (its heartbeats included). For the hot
  // reader of a process (the learner's batches).
  Reader(Bus& bus, const std::string& topic_name, const std::string& profile, uint32_t max_sample_bytes,
         OnData on_data = {}, bool preallocate = false)
      : bus_(bus), max_sample_bytes_(max_sample_bytes), on_data_(std::move(on_data)) {
    fdds::Topic* t = bus.topic(topic_name, fdds::TypeSupport(new BoundedType<T, PubSubType>(max_sample_bytes)));
    type_name_ = t->get_type_name();
    fdds::TypeSupport registered = bus.participant()->find_type(t->get_type_name());
    if (registered.empty() || registered->m_typeSize != max_sample_bytes) {
      throw std::logic_error("DDS topic " + topic_name + " was created without the bound of " +
                             std::to_string(max_sample_bytes) + " bytes per sample");
    }
    fdds::DataReaderQos qos = bus.reader_qos(topic_name, profile);
    qos.endpoint().history_memory_policy = eprosima::fastrtps::rtps::PREALLOCATED_MEMORY_MODE;
    count_samples_refused_for_size();
    if (preallocate && qos.resource_limits().max_samples > 0) {
      qos.resource_limits().allocated_samples = qos.resource_limits().max_samples;
      with_mapped_allocations(max_sample_bytes, [&] { reader_ = bus.subscriber()->create_datareader(t, qos, this); });
    } else {
      reader_ = bus.subscriber()->create_datareader(t, qos, this);
    }
    if (!reader_) {
      throw std::runtime_error("cannot create DDS reader for " + topic_name + " with profile '" + profile + "'");
    }
  }
  ~Reader() override {
    reader_->set_listener(nullptr);
    bus_.subscriber()->delete_datareader(reader_);
  }
  // Takes the next valid sample, if any; never blocks. info: its SampleInfo (the writer's GUID).
  bool take(T& out) { return take_from(reader_, out); }
  fdds::DataReader* dds_reader() const { return reader_; }
  bool take(T& out, fdds::SampleInfo& info) { return take_from(reader_, out, info); }
  static bool take_from(fdds::DataReader* reader, T& out) {
    fdds::SampleInfo info;
    return take_from(reader, out, info);
  }
  // A malformed sample (CheckedType) is taken from the history and skipped: counted, never returned.
  static bool take_from(fdds::DataReader* reader, T& out, fdds::SampleInfo& info) {
    take_malformed_mark();
    while (reader->take_next_sample(&out, &info) == eprosima::fastrtps::types::ReturnCode_t::RETCODE_OK) {
      if (take_malformed_mark()) continue;
      if (info.valid_data) return true;
    }
    return false;
  }
  // Waits until data may be available or the timeout passes.
  void wait(double seconds) {
    std::unique_lock<std::mutex> lk(mu_);
    cv_.wait_for(lk, std::chrono::duration<double>(seconds), [&] { return pending_; });
    pending_ = false;
  }
  int matched() const {
    fdds::SubscriptionMatchedStatus st;
    reader_->get_subscription_matched_status(st);
    return st.current_count;
  }
  void on_data_available(fdds::DataReader* reader) override {
    if (on_data_) on_data_(reader);
    std::lock_guard<std::mutex> lk(mu_);
    pending_ = true;
    cv_.notify_all();
  }
  // The writers matched with this reader, kept from the match notifications (Fast DDS 2.9's
  // get_matched_publications is not implemented). A writer leaves when its participant leaves or
  // its lease runs out.
  void on_subscription_matched(fdds::DataReader*, const fdds::SubscriptionMatchedStatus& info) override {
    const eprosima::fastrtps::rtps::GUID_t writer =
        eprosima::fastrtps::rtps::iHandle2GUID(info.last_publication_handle);
    std::lock_guard<std::mutex> lk(matched_mu_);
    if (info.current_count_change > 0) matched_writers_.insert(writer);
    if (info.current_count_change < 0) matched_writers_.erase(writer);
  }
  bool writer_matched(const eprosima::fastrtps::rtps::GUID_t& writer) const {
    std::lock_guard<std::mutex> lk(matched_mu_);
    return matched_writers_.count(writer) > 0;
  }
  // Samples refused for their size (bounded constructor) in this process so far.
  uint64_t refused() const { return max_sample_bytes_ ? samples_refused_for_size(max_sample_bytes_) : 0; }
  // The bound of the bounded constructor; 0 for none.
  uint32_t max_sample_bytes() const { return max_sample_bytes_; }
  // Samples of this reader's type refused as malformed in this process so far, and why the last was.
  uint64_t malformed() const { return samples_malformed(type_name_); }
  std::string last_malformed_reason() const { return last_malformed(type_name_); }

 private:
  Bus& bus_;
  uint32_t max_sample_bytes_ = 0;
  std::string type_name_;
  OnData on_data_;
  fdds::DataReader* reader_ = nullptr;
  std::mutex mu_;
  std::condition_variable cv_;
  mutable std::mutex matched_mu_;
  std::set<eprosima::fastrtps::rtps::GUID_t> matched_writers_;
  bool pending_ = false;
};

// PolicyWeights <-> PolicyParams. from_wire throws std::invalid_argument on inconsistent data.
void to_wire(const PolicyParams& p, const std::string& experiment_id, farm::msg::PolicyWeights& w);
PolicyParams from_wire(const farm::msg::PolicyWeights& w);

std::string hostname();
uint64_t random_session_id();

// The participant a sample came from, as a map key: the GUID prefix of its writer
// (SampleInfo::sample_identity.writer_guid()), which every writer of one participant shares. A
// worker's batches, heartbeats and evaluation answers come from one participant: the learner binds
// each worker stream to it and takes a worker's answers only from it.
inline std::string participant_key(const eprosima::fastrtps::rtps::GUID_t& writer) {
  return std::string(reinterpret_cast<const char*>(writer.guidPrefix.value), sizeof writer.guidPrefix.value);
}

}  // namespace farm::dds
