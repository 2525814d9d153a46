// Who wrote a sample, under DDS Security, by what access control enforces with each participant's
// authenticated certificate rather than by what a participant says of itself.
//
// A worker's signed permissions (deploy/make-pki.sh) let it write TransitionBatch, WorkerStatus and
// EvaluationAnswer only in its own partition, worker/<name>. Fast DDS's access control checks a
// remote writer's partitions against the grant of the certificate its participant authenticated
// with (Permissions::check_remote_datawriter) before the writer is matched, so a writer discovered
// in worker/w1 and matched belongs to w1's certificate. The identity token (dds.cert.sn) is not
// used: Fast DDS 2.9.1 never compares it with the authenticated certificate.
//
// Fast DDS 2.9.1 checks the partitions again when a writer announces new ones, and on a refusal
// only logs and keeps the match: a writer that moves to another partition after matching keeps
// delivering. So a writer's name is fixed at its first discovery, and a writer whose partitions
// change afterwards is tainted: it names no one from then on.
#pragma once

#include <fastdds/rtps/common/Guid.h>

#include <cstdint>
#include <map>
#include <mutex>
#include <set>
#include <string>
#include <vector>

namespace farm::dds {

// The partition a worker named `name` writes in.
std::string worker_partition(const std::string& name);
// NAME when partitions are exactly one "worker/NAME" with NAME a valid participant name (letters,
// digits, '.', '_', '-'), else "".
std::string worker_of_partitions(const std::vector<std::string>& partitions);
// "[a;b]", for messages.
std::string partitions_text(const std::vector<std::string>& partitions);

class WriterNames {
 public:
  enum class Event { kDiscovered, kChanged, kRemoved };
  static constexpr size_t kMaxWriters = 16384;

  // A remote writer as discovery announced it (DomainParticipantListener::on_publisher_discovery).
  void writer(const eprosima::fastrtps::rtps::GUID_t& guid, const std::vector<std::string>& partitions, Event event);
  // The worker name a writer's partition gave it at discovery; "" with *why when it has none.
  std::string name_of(const eprosima::fastrtps::rtps::GUID_t& guid, std::string* why = nullptr) const;

 private:
  struct Entry {
    std::vector<std::string> partitions;  // as first discovered
    std::string name;
    std::string taint;  // why it names no one
    bool gone = false;
    uint64_t order = 0;
  };
  mutable std::mutex mu_;
  std::map<eprosima::fastrtps::rtps::GUID_t, Entry> writers_;
  uint64_t next_order_ = 0;
};

// The worker names the permissions document grants, read from DIR's signed permissions after
// checking their signature against the permissions CA (the same files Fast DDS reads): the CN of
// each grant's subject that may publish in worker/<CN>. Returns "" and fills names, or why the file
// was refused (names untouched).
std::string load_worker_grants(const std::string& permissions_p7s, const std::string& ca_pem,
                               std::set<std::string>& names);

// A revocation list in PEM: "" when it can be used now, else why not (unreadable, not yet valid,
// expired).
std::string crl_problem(const std::string& crl_pem);

}  // namespace farm::dds
