// The wire layouts (common/wire_check.h) against the generated code: every type, filled so that each
// sequence and string has elements and odd lengths shift the alignment, walks to its exact end;
// broken samples are refused with the field named; and the checked type a reader uses turns any
// malformed sample into a refusal instead of an exception.
#include <gtest/gtest.h>

#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <random>
#include <string>

#include "dds.h"
#include "farmPubSubTypes.h"
#include "wire_check.h"

namespace {

using eprosima::fastrtps::rtps::SerializedPayload_t;
using farm::wire::Kind;

template <class T, class PubSubType>
std::vector<uint8_t> serialized(T& sample) {
  PubSubType type;
  SerializedPayload_t payload(type.getSerializedSizeProvider(&sample)() + 8);
  EXPECT_TRUE(type.serialize(&sample, &payload));
  return std::vector<uint8_t>(payload.data, payload.data + payload.length);
}

farm::msg::PolicyWeights weights() {
  farm::msg::PolicyWeights w;
  w.experiment_id("e");
  w.version(7);
  w.head(1);
  w.layer_sizes({3, 5, 1});
  w.activation(2);
  w.obs_mean({1.f, 2.f, 3.f});
  w.obs_std({1.f});
  w.parameters({1.f, 2.f});
  w.epsilon(0.5f);
  w.log_std({0.1f});
  w.batch_quota(3);
  return w;
}

farm::msg::TransitionBatch batch() {
  farm::msg::TransitionBatch b;
  b.experiment_id("exp");  // 4 bytes with its terminator
  b.worker_id("w1");       // 3: the next u64 needs padding
  b.worker_session(5);
  b.sequence_number(6);
  b.policy_version(7);
  b.num_steps(1);
  b.num_envs(2);
  b.obs_dim(3);
  b.act_dim(1);
  b.observations({1, 2, 3, 4, 5, 6});
  b.actions({1, 2});
  b.rewards({1, 2});
  b.terminated({0, 1});
  b.truncated({1, 0, 1});  // odd: the next float sequence's count needs padding
  b.log_probs({0.5f, 0.25f});
  b.next_observations({1, 2, 3, 4, 5, 6});
  b.final_index({1});
  b.final_observations({1, 2, 3});
  farm::msg::EpisodeSummary e;
  e.env(1);
  e.terminated(true);
  e.metrics({1.f, 2.f});
  b.episodes({e, e});
  b.end_of_stream(true);
  return b;
}

// A type's walk over its own serialization: well-formed, every field reached, exact end.
template <class T, class PubSubType>
void expect_walks(T sample, const farm::wire::Layout& layout, size_t min_fields) {
  const std::vector<uint8_t> bytes = serialized<T, PubSubType>(sample);
  size_t fields = 0, end = 0;
  const farm::wire::Check walked = farm::wire::walk(
      layout, bytes.data(), bytes.size(), [&](const std::string&, Kind, size_t) { ++fields; }, &end);
  EXPECT_TRUE(walked.ok()) << layout.name << ": " << walked.text();
  EXPECT_GE(fields, min_fields) << layout.name;
  // The walk ends on the sample's last byte: a field added to the IDL and not to the layout (or one
  // of another width) leaves bytes unwalked or runs past the end.
  EXPECT_EQ(end, bytes.size()) << layout.name;
  EXPECT_EQ(std::string(PubSubType().getName()), layout.name);
  // One byte less is truncated.
  EXPECT_FALSE(farm::wire::walk(layout, bytes.data(), bytes.size() - 4).ok()) << layout.name;
}

TEST(WireCheck, EveryTypeWalksToItsEnd) {
  expect_walks<farm::msg::TransitionBatch, farm::msg::TransitionBatchPubSubType>(
      batch(), farm::wire::transition_batch(), 20 + 2 * 5);
  farm::msg::ExperimentSpec s;
  s.experiment_id("ab");
  s.config_text("x: 1\n");
  s.task_name("p");
  s.seed(3);
  s.finished(true);
  expect_walks<farm::msg::ExperimentSpec, farm::msg::ExperimentSpecPubSubType>(s, farm::wire::experiment_spec(), 10);
  expect_walks<farm::msg::PolicyWeights, farm::msg::PolicyWeightsPubSubType>(weights(), farm::wire::policy_weights(),
                                                                             13);
  farm::msg::EvaluationRequest q;
  q.experiment_id("e");
  q.worker_id("w12");
  q.seed(9);
  q.policy(weights());
  q.first_episode(4);
  expect_walks<farm::msg::EvaluationRequest, farm::msg::EvaluationRequestPubSubType>(
      q, farm::wire::evaluation_request(), 8 + 13);
  farm::msg::EvaluationAnswer a;
  a.experiment_id("e");
  a.worker_id("w");
  farm::msg::EvaluationEpisode ep;
  ep.terminated(true);
  ep.metrics({1.f});
  a.episodes({ep, ep, ep});
  a.seconds(1.5);
  a.error("no");
  expect_walks<farm::msg::EvaluationAnswer, farm::msg::EvaluationAnswerPubSubType>(a, farm::wire::evaluation_answer(),
                                                                                   9 + 3 * 4);
  farm::msg::WorkerStatus st;
  st.worker_id("w");
  st.host("hh");
  st.state("running");
  st.last_error("x");
  expect_walks<farm::msg::WorkerStatus, farm::msg::WorkerStatusPubSubType>(st, farm::wire::worker_status(), 12);
  farm::msg::LearnerStats ls;
  ls.experiment_id("e");
  ls.workers(3);
  farm::msg::LearnerStat stat;
  stat.name("update_to_data");
  stat.unit("");
  stat.value(0.25);
  ls.stats({stat, stat});
  expect_walks<farm::msg::LearnerStats, farm::msg::LearnerStatsPubSubType>(ls, farm::wire::learner_stats(), 17 + 2 * 3);
}

// The offset of a field reached by the walk.
size_t offset_of(const std::vector<uint8_t>& bytes, const farm::wire::Layout& layout, const std::string& path) {
  size_t at = 0;
  farm::wire::walk(layout, bytes.data(), bytes.size(), [&](const std::string& p, Kind, size_t o) {
    if (p == path) at = o;
  });
  return at;
}

TEST(WireCheck, BrokenSamplesAreRefusedNamingTheField) {
  auto b = batch();
  const std::vector<uint8_t> good = serialized<farm::msg::TransitionBatch, farm::msg::TransitionBatchPubSubType>(b);
  const auto& layout = farm::wire::transition_batch();

  std::vector<uint8_t> bad = good;
  bad[offset_of(good, layout, "end_of_stream")] = 2;
  farm::wire::Check c = farm::wire::walk(layout, bad.data(), bad.size());
  EXPECT_EQ(c.fault, farm::wire::Fault::Bool);
  EXPECT_EQ(c.field, "end_of_stream");

  bad = good;
  bad[offset_of(good, layout, "episodes[1].terminated")] = 255;
  c = farm::wire::walk(layout, bad.data(), bad.size());
  EXPECT_EQ(c.fault, farm::wire::Fault::Bool);
  EXPECT_EQ(c.field, "episodes[1].terminated");

  // A count that claims every byte left, as a length bomb does, in each sequence in turn: refused at
  // that field, or (octets, whose count the bytes left can hold) at the next one, which has none left.
  for (const char* seq : {"observations", "final_index", "episodes", "worker_id", "terminated"}) {
    bad = good;
    const size_t at = offset_of(good, layout, seq);
    ASSERT_GT(at, 0u) << seq;
    const uint32_t left = uint32_t(bad.size() - at - 4);
    std::memcpy(&bad[at], &left, 4);
    c = farm::wire::walk(layout, bad.data(), bad.size());
    const std::string named = std::string(seq) == "terminated" ? "truncated" : seq;
    EXPECT_FALSE(c.ok()) << seq;
    EXPECT_EQ(c.field.substr(0, named.size()), named) << seq << ": " << c.text();
  }
  // A count of 2^32 - 1 elements.
  bad = good;
  std::memset(&bad[offset_of(good, layout, "rewards")], 0xff, 4);
  EXPECT_EQ(farm::wire::walk(layout, bad.data(), bad.size()).fault, farm::wire::Fault::Count);

  // Not plain CDR, no header, trailing bytes, a string without its terminator.
  bad = good;
  bad[1] = 3;
  EXPECT_EQ(farm::wire::walk(layout, bad.data(), bad.size()).fault, farm::wire::Fault::Encapsulation);
  EXPECT_EQ(farm::wire::walk(layout, good.data(), 2).fault, farm::wire::Fault::NoHeader);
  bad = good;
  bad.insert(bad.end(), 8, 0);
  EXPECT_EQ(farm::wire::walk(layout, bad.data(), bad.size()).fault, farm::wire::Fault::Trailing);
  bad = good;
  const size_t id = offset_of(good, layout, "experiment_id");
  bad[id + 4 + 3] = 'x';  // "exp\0" -> "expx"
  c = farm::wire::walk(layout, bad.data(), bad.size());
  EXPECT_EQ(c.fault, farm::wire::Fault::Terminator);
  EXPECT_EQ(c.field, "experiment_id");
}

// What a reader's type does with what arrives: a well-formed sample decodes; a malformed one, whose
// decoding by the generated code throws (a boolean byte of 2) or allocates what its counts claim,
// is refused, counted under its type and marked for the take in progress.
TEST(WireCheck, CheckedTypeRefusesInsteadOfThrowing) {
  using Checked = farm::dds::CheckedType<farm::msg::TransitionBatch, farm::msg::TransitionBatchPubSubType>;
  Checked type;
  auto b = batch();
  std::vector<uint8_t> good = serialized<farm::msg::TransitionBatch, farm::msg::TransitionBatchPubSubType>(b);
  SerializedPayload_t payload(uint32_t(good.size()));
  auto load = [&](const std::vector<uint8_t>& bytes) {
    std::memcpy(payload.data, bytes.data(), bytes.size());
    payload.length = uint32_t(bytes.size());
  };
  const uint64_t before = farm::dds::samples_malformed(type.getName());
  farm::msg::TransitionBatch out;
  load(good);
  farm::dds::take_malformed_mark();
  EXPECT_TRUE(type.deserialize(&payload, &out));
  EXPECT_FALSE(farm::dds::take_malformed_mark());
  EXPECT_EQ(out.observations().size(), 6u);
  EXPECT_TRUE(out.end_of_stream());

  std::vector<uint8_t> bad = good;
  bad[offset_of(good, farm::wire::transition_batch(), "end_of_stream")] = 2;
  // The generated code alone throws on it (what ended a learner).
  {
    farm::msg::TransitionBatchPubSubType plain;
    load(bad);
    farm::msg::TransitionBatch raw;
    EXPECT_ANY_THROW(plain.deserialize(&payload, &raw));
  }
  load(bad);
  EXPECT_FALSE(type.deserialize(&payload, &out));
  EXPECT_TRUE(farm::dds::take_malformed_mark());
  EXPECT_FALSE(farm::dds::take_malformed_mark());
  EXPECT_TRUE(out.observations().empty());  // nothing of it is left in the sample
  EXPECT_EQ(farm::dds::samples_malformed(type.getName()), before + 1);
  EXPECT_EQ(farm::dds::last_malformed(type.getName()),
            farm::wire::walk(farm::wire::transition_batch(), bad.data(), bad.size()).text());
  // A refusal, then a good sample in the same take (Fast DDS 2.9.1 goes on after the refused sample
  // and decodes the next): the mark is the last decoding's, so the good sample is not skipped.
  load(bad);
  EXPECT_FALSE(type.deserialize(&payload, &out));
  load(good);
  EXPECT_TRUE(type.deserialize(&payload, &out));
  EXPECT_FALSE(farm::dds::take_malformed_mark());
}

// Random mutations (seeded) of a well-formed sample of one type: the checked type never throws, and
// it is no blanket refusal (some mutations, of values rather than structure, decode).
template <class T, class PubSubType>
void mutations_never_throw(T sample, int rounds, uint32_t seed) {
  farm::dds::CheckedType<T, PubSubType> type;
  const std::vector<uint8_t> good = serialized<T, PubSubType>(sample);
  std::mt19937 rng(seed);
  SerializedPayload_t payload(uint32_t(good.size()));
  int accepted = 0;
  for (int i = 0; i < rounds; ++i) {
    std::vector<uint8_t> bad = good;
    const int flips = 1 + int(rng() % 4);
    for (int f = 0; f < flips; ++f) bad[4 + rng() % (bad.size() - 4)] = uint8_t(rng());
    if (rng() % 8 == 0) bad.resize(4 + rng() % (bad.size() - 4));
    std::memcpy(payload.data, bad.data(), bad.size());
    payload.length = uint32_t(bad.size());
    T out;
    bool ok = false;
    EXPECT_NO_THROW(ok = type.deserialize(&payload, &out)) << type.getName() << " round " << i;
    accepted += ok;
    farm::dds::take_malformed_mark();
  }
  EXPECT_GT(accepted, 0) << type.getName();
}

TEST(WireCheck, MutatedSamplesOfEveryTopicNeverThrow) {
  mutations_never_throw<farm::msg::TransitionBatch, farm::msg::TransitionBatchPubSubType>(batch(), 20000, 17);
  mutations_never_throw<farm::msg::PolicyWeights, farm::msg::PolicyWeightsPubSubType>(weights(), 5000, 18);
  farm::msg::ExperimentSpec s;
  s.experiment_id("ab");
  s.config_text("x: 1\n");
  s.finished(true);
  mutations_never_throw<farm::msg::ExperimentSpec, farm::msg::ExperimentSpecPubSubType>(s, 5000, 19);
  farm::msg::EvaluationRequest q;
  q.worker_id("w12");
  q.policy(weights());
  mutations_never_throw<farm::msg::EvaluationRequest, farm::msg::EvaluationRequestPubSubType>(q, 5000, 20);
  farm::msg::EvaluationAnswer a;
  farm::msg::EvaluationEpisode ep;
  ep.terminated(true);
  ep.metrics({1.f});
  a.episodes({ep, ep});
  a.error("e");
  mutations_never_throw<farm::msg::EvaluationAnswer, farm::msg::EvaluationAnswerPubSubType>(a, 5000, 21);
  farm::msg::WorkerStatus st;
  st.worker_id("w");
  st.state("running");
  mutations_never_throw<farm::msg::WorkerStatus, farm::msg::WorkerStatusPubSubType>(st, 5000, 22);
  farm::msg::LearnerStats ls;
  ls.experiment_id("e");
  mutations_never_throw<farm::msg::LearnerStats, farm::msg::LearnerStatsPubSubType>(ls, 5000, 23);
}

// The regression corpus, tests/data/wire_corpus/<type>_<kind>.hex: samples of each kind that ended
// a learner or a worker before the readers checked them (farm_intruder --malformed KIND --dump DIR
// wrote them). Each is refused by its type's checked decoding, without an exception, and named.
template <class T, class PubSubType>
bool refused(const std::vector<uint8_t>& bytes, std::string* why) {
  farm::dds::CheckedType<T, PubSubType> type;
  SerializedPayload_t payload(uint32_t(bytes.size()));
  std::memcpy(payload.data, bytes.data(), bytes.size());
  payload.length = uint32_t(bytes.size());
  T out;
  const bool ok = type.deserialize(&payload, &out);
  farm::dds::take_malformed_mark();
  *why = farm::dds::last_malformed(type.getName());
  return !ok;
}

std::vector<uint8_t> read_hex(const std::string& path) {
  std::ifstream in(path);
  std::vector<uint8_t> bytes;
  std::string line;
  while (std::getline(in, line))
    for (size_t i = 0; i + 1 < line.size(); i += 2)
      bytes.push_back(uint8_t(std::stoul(line.substr(i, 2), nullptr, 16)));
  return bytes;
}

TEST(WireCheck, TheRegressionCorpusIsRefused) {
  using namespace farm::msg;
  const std::map<std::string, std::function<bool(const std::vector<uint8_t>&, std::string*)>> by_type = {
      {"TransitionBatch", refused<TransitionBatch, TransitionBatchPubSubType>},
      {"WorkerStatus", refused<WorkerStatus, WorkerStatusPubSubType>},
      {"EvaluationAnswer", refused<EvaluationAnswer, EvaluationAnswerPubSubType>},
      {"ExperimentSpec", refused<ExperimentSpec, ExperimentSpecPubSubType>},
      {"PolicyWeights", refused<PolicyWeights, PolicyWeightsPubSubType>},
      {"EvaluationRequest", refused<EvaluationRequest, EvaluationRequestPubSubType>},
  };
  int files = 0;
  for (const auto& e : std::filesystem::directory_iterator(std::string(FARM_SOURCE_DIR) + "/tests/data/wire_corpus")) {
    const std::string name = e.path().stem().string();
    SCOPED_TRACE(name);
    const auto it = by_type.find(name.substr(0, name.find('_')));
    ASSERT_NE(it, by_type.end()) << "a corpus file of no known type";
    const auto bytes = read_hex(e.path().string());
    ASSERT_GE(bytes.size(), 4u);
    std::string why;
    bool refused_it = false;
    EXPECT_NO_THROW(refused_it = it->second(bytes, &why));
    EXPECT_TRUE(refused_it);
    EXPECT_FALSE(why.empty());
    ++files;
  }
  EXPECT_GE(files, 15);  // every topic, each kind it can be broken by
}

}  // namespace
