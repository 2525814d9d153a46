// Who wrote a sample under DDS Security (common/trust.h): a writer's worker name comes from the
// partition access control let it write in, fixed at its discovery; the identity token plays no
// part. And the worker names a signed permissions document grants, as a learner reads them again
// after deploy/make-pki.sh --revoke.
#include <gtest/gtest.h>

#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <set>
#include <string>

#include "dds.h"
#include "trust.h"

using eprosima::fastrtps::rtps::GUID_t;
using farm::dds::WriterNames;

namespace {

GUID_t writer_guid(uint8_t participant, uint8_t entity) {
  GUID_t g;
  g.guidPrefix.value[0] = participant;
  g.entityId.value[3] = entity;
  return g;
}

}  // namespace

TEST(Trust, WorkerPartitionNamesOnlyOneWellFormedWorker) {
  using farm::dds::worker_of_partitions;
  EXPECT_EQ(worker_of_partitions({"worker/w1"}), "w1");
  EXPECT_EQ(worker_of_partitions({"worker/host-b.2_x"}), "host-b.2_x");
  EXPECT_EQ(worker_of_partitions({}), "");
  EXPECT_EQ(worker_of_partitions({""}), "");
  EXPECT_EQ(worker_of_partitions({"worker/*"}), "");
  EXPECT_EQ(worker_of_partitions({"worker/w?"}), "");
  EXPECT_EQ(worker_of_partitions({"worker/"}), "");
  EXPECT_EQ(worker_of_partitions({"worker/w1", "worker/w2"}), "");
  EXPECT_EQ(worker_of_partitions({"learner/w1"}), "");
}

// The attack of a participant that authenticated with w1's certificate and says w2 in its identity
// token: its writer was discovered in worker/w1 (the one partition w1's grant allows, checked by
// access control against the real certificate), so it is w1, whatever the token said.
TEST(Trust, NameComesFromTheDiscoveredPartitionNotTheToken) {
  WriterNames names;
  const GUID_t liar = writer_guid(1, 3);
  // What the token says is not an input at all: only the partitions discovery announced.
  names.writer(liar, {"worker/w1"}, WriterNames::Event::kDiscovered);
  std::string why;
  EXPECT_EQ(names.name_of(liar, &why), "w1");
  // An unknown writer names no one.
  EXPECT_EQ(names.name_of(writer_guid(2, 3), &why), "");
  EXPECT_NE(why.find("not discovered"), std::string::npos) << why;
  // A writer in the default partition (a learner's, or a worker of a PKI without partitions) neither.
  names.writer(writer_guid(3, 3), {}, WriterNames::Event::kDiscovered);
  EXPECT_EQ(names.name_of(writer_guid(3, 3), &why), "");
  EXPECT_NE(why.find("not in one worker/<name>"), std::string::npos) << why;
}

// Fast DDS 2.9.1 keeps a writer matched when it moves to a partition its grant does not allow (the
// re-check fails and is only logged): such a writer is tainted for good, it never takes the new name.
TEST(Trust, WriterThatChangesPartitionIsTainted) {
  WriterNames names;
  const GUID_t w = writer_guid(1, 3);
  names.writer(w, {"worker/w1"}, WriterNames::Event::kDiscovered);
  names.writer(w, {"worker/w1"}, WriterNames::Event::kChanged);  // another QoS change: same partition
  EXPECT_EQ(names.name_of(w), "w1");
  names.writer(w, {"worker/w2"}, WriterNames::Event::kChanged);
  std::string why;
  EXPECT_EQ(names.name_of(w, &why), "");
  EXPECT_NE(why.find("changed after discovery from [worker/w1] to [worker/w2]"), std::string::npos) << why;
  names.writer(w, {"worker/w1"}, WriterNames::Event::kChanged);  // moving back does not clean it
  EXPECT_EQ(names.name_of(w), "");
  // Removed: still tainted (its last samples may wait in a reader).
  names.writer(w, {"worker/w1"}, WriterNames::Event::kRemoved);
  EXPECT_EQ(names.name_of(w), "");
  // A writer first heard of by a change has no known first partition.
  names.writer(writer_guid(2, 3), {"worker/w2"}, WriterNames::Event::kChanged);
  EXPECT_EQ(names.name_of(writer_guid(2, 3)), "");
}

TEST(Trust, WriterTableIsBounded) {
  WriterNames names;
  for (size_t i = 0; i < WriterNames::kMaxWriters + 10; ++i) {
    GUID_t g;
    std::memcpy(g.guidPrefix.value, &i, sizeof i);
    names.writer(g, {"worker/w" + std::to_string(i)}, WriterNames::Event::kDiscovered);
  }
  GUID_t last;
  const size_t i = WriterNames::kMaxWriters + 9;
  std::memcpy(last.guidPrefix.value, &i, sizeof i);
  EXPECT_EQ(names.name_of(last), "w" + std::to_string(i));
  EXPECT_EQ(names.name_of(GUID_t()), "");  // the first, evicted: refused, never renamed
}

// The grants a learner reads: only signed by the permissions CA, and only names that may write in
// their own worker partition. make-pki.sh --revoke drops a name; a document not signed by the CA is
// refused and leaves the caller's names as they were.
TEST(Trust, WorkerGrantsFromSignedPermissions) {
  char tmpl[] = "/tmp/farm-trust-XXXXXX";
  ASSERT_NE(mkdtemp(tmpl), nullptr);
  const std::string d = tmpl, pki = "bash " + std::string(FARM_SOURCE_DIR) + "/deploy/make-pki.sh ";
  ASSERT_EQ(std::system((pki + d + "/pki learner:learner worker:w1 worker:w2 worker:learnerbox-1 monitor:mon > " + d +
                         "/pki.log 2>&1")
                            .c_str()),
            0);
  std::set<std::string> names = {"stale"};
  EXPECT_EQ(farm::dds::load_worker_grants(d + "/pki/learner/permissions.p7s", d + "/pki/learner/ca.cert.pem", names),
            "");
  EXPECT_EQ(names, (std::set<std::string>{"w1", "w2", "learnerbox-1"}));
  // Bare names are refused: a role is never guessed from a name.
  EXPECT_NE(std::system((pki + d + "/pki w3 >> " + d + "/pki.log 2>&1").c_str()), 0);
  ASSERT_EQ(std::system((pki + d + "/pki --revoke w2 >> " + d + "/pki.log 2>&1").c_str()), 0);
  EXPECT_EQ(farm::dds::load_worker_grants(d + "/pki/learner/permissions.p7s", d + "/pki/learner/ca.cert.pem", names),
            "");
  EXPECT_EQ(names, (std::set<std::string>{"w1", "learnerbox-1"}));
  EXPECT_TRUE(std::filesystem::exists(d + "/pki/learner/crl.pem"));
  EXPECT_EQ(farm::dds::crl_problem(d + "/pki/learner/crl.pem"), "");
  // Signed by another CA: refused, the names stay.
  ASSERT_EQ(std::system((pki + d + "/rogue worker:w9 >> " + d + "/pki.log 2>&1").c_str()), 0);
  const std::string why =
      farm::dds::load_worker_grants(d + "/rogue/w9/permissions.p7s", d + "/pki/learner/ca.cert.pem", names);
  EXPECT_NE(why.find("is not signed by the permissions CA"), std::string::npos) << why;
  EXPECT_EQ(names, (std::set<std::string>{"w1", "learnerbox-1"}));
  std::filesystem::remove_all(d);
}
