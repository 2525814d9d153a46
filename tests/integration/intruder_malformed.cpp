// farm_intruder --malformed KIND: samples of every topic whose bytes are not a valid encoding of
// their type, written through a type that sends raw bytes under the farm's type names. Each starts
// as a well-formed sample of the experiment, serialized by the generated code, and is then broken
// one way (KIND):
//   bool      a boolean byte set to 2 (the types that have one)
//   length    every sequence's and string's count set to the number of bytes left in the sample
//             (the batch carries a megabyte of episode metrics, so that the counts claim a lot)
//   truncate  the sample cut after half its bytes
//   fuzz      every sample written mutated afresh (seeded): one to four of a byte set at random,
//             a field's word (count, length or value) set to a random or extreme number, the
//             sample cut anywhere, bytes inserted or removed
// To the learner: TransitionBatch, WorkerStatus, EvaluationAnswer; to the workers: ExperimentSpec,
// PolicyWeights, EvaluationRequest. One of each every 100 ms for --seconds once matched; it prints
// how many of each it wrote and records them (a malformed event a topic).
#include "intruder_malformed.h"

#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <memory>
#include <random>
#include <thread>
#include <vector>

#include "intruder_events.h"
#include "meter.h"
#include "wire_check.h"

namespace {

namespace fdds = eprosima::fastdds::dds;
using eprosima::fastrtps::rtps::SerializedPayload_t;

struct RawSample {
  std::vector<uint8_t> bytes;
};

// Sends RawSample's bytes as they are, under another type's name.
class RawType : public fdds::TopicDataType {
 public:
  RawType(const std::string& name, uint32_t max_bytes) {
    setName(name.c_str());
    m_typeSize = max_bytes;
    m_isGetKeyDefined = false;
  }
  bool serialize(void* data, SerializedPayload_t* payload) override {
    const auto& b = static_cast<RawSample*>(data)->bytes;
    if (b.size() < 4 || b.size() > payload->max_size) return false;
    std::memcpy(payload->data, b.data(), b.size());
    payload->length = uint32_t(b.size());
    payload->encapsulation = b[1] ? CDR_LE : CDR_BE;
    return true;
  }
  bool deserialize(SerializedPayload_t*, void*) override { return false; }
  std::function<uint32_t()> getSerializedSizeProvider(void* data) override {
    return [data] { return uint32_t(static_cast<RawSample*>(data)->bytes.size()); };
  }
  void* createData() override { return new RawSample(); }
  void deleteData(void* data) override { delete static_cast<RawSample*>(data); }
  bool getKey(void*, eprosima::fastrtps::rtps::InstanceHandle_t*, bool) override { return false; }
};

// A well-formed sample's bytes, as the generated type serializes it.
template <class T, class PubSubType>
std::vector<uint8_t> serialized(T& sample) {
  PubSubType type;
  SerializedPayload_t payload(type.getSerializedSizeProvider(&sample)() + 8);
  if (!type.serialize(&sample, &payload)) throw std::runtime_error("cannot serialize a sample to break");
  return std::vector<uint8_t>(payload.data, payload.data + payload.length);
}

// The sample broken one way (see the top); empty when the type has nothing to break that way.
std::vector<uint8_t> broken(std::vector<uint8_t> b, const farm::wire::Layout& layout, const std::string& kind) {
  if (kind == "truncate") {
    b.resize(4 + (b.size() - 4) / 2);
    return b;
  }
  std::vector<std::pair<farm::wire::Kind, size_t>> fields;
  const std::string why =
      farm::wire::walk(layout, b.data(), b.size(), [&](const std::string&, farm::wire::Kind k, size_t at) {
        fields.emplace_back(k, at);
      }).text();
  if (!why.empty()) throw std::runtime_error("the well-formed sample does not walk: " + why);
  bool changed = false;
  for (const auto& [k, at] : fields) {
    if (kind == "bool" && k == farm::wire::Kind::Bool) {
      b[at] = 2;
      changed = true;
    }
    if (kind == "length" && k != farm::wire::Kind::Bool && k != farm::wire::Kind::U32 && k != farm::wire::Kind::U64 &&
        k != farm::wire::Kind::F32 && k != farm::wire::Kind::F64) {
      const uint32_t left = uint32_t(b.size() - at - 4);
      std::memcpy(&b[at], &left, 4);  // the samples are little-endian, as this host writes them
      changed = true;
    }
  }
  if (!changed) b.clear();
  return b;
}

// `good` mutated one to four ways, for --malformed fuzz. The encapsulation header is left alone
// in most samples, so that the mutations reach the walk and the decoder behind it.
std::vector<uint8_t> fuzzed(const std::vector<uint8_t>& good, const farm::wire::Layout& layout, std::mt19937_64& rng) {
  std::vector<size_t> words;  // offsets of the fields' first words, from the well-formed sample
  farm::wire::walk(layout, good.data(), good.size(),
                   [&](const std::string&, farm::wire::Kind, size_t at) { words.push_back(at); });
  std::vector<uint8_t> b = good;
  auto pick = [&](size_t n) { return size_t(rng() % std::max<size_t>(n, 1)); };
  const int edits = 1 + int(rng() % 4);
  for (int e = 0; e < edits && b.size() > 4; ++e) {
    const size_t from = rng() % 16 == 0 ? 0 : 4;
    switch (rng() % 5) {
      case 0:  // a byte
        b[from + pick(b.size() - from)] = uint8_t(rng());
        break;
      case 1: {  // a field's word: random, or one of the extremes a decoder must bound
        if (words.empty()) break;
        const size_t at = words[pick(words.size())];
        if (at + 4 > b.size()) break;
        const uint32_t extremes[] = {0u, 1u, 0x7fffffffu, 0x80000000u, 0xffffffffu, uint32_t(b.size())};
        const uint32_t v = rng() % 2 ? uint32_t(rng()) : extremes[pick(6)];
        std::memcpy(&b[at], &v, 4);
        break;
      }
      case 2:  // cut anywhere past the header
        b.resize(4 + pick(b.size() - 4));
        break;
      case 3: {  // bytes inserted
        const size_t at = from + pick(b.size() - from), n = 1 + pick(8);
        std::vector<uint8_t> extra(n);
        for (auto& x : extra) x = uint8_t(rng());
        b.insert(b.begin() + std::ptrdiff_t(at), extra.begin(), extra.end());
        break;
      }
      default: {  // bytes removed
        const size_t at = from + pick(b.size() - from), n = std::min(b.size() - at, 1 + pick(8));
        b.erase(b.begin() + std::ptrdiff_t(at), b.begin() + std::ptrdiff_t(at + n));
      }
    }
  }
  if (b.size() < 4) b.resize(4, 0);  // the raw type sends at least a header
  return b;
}

// bytes as hex, 32 to a line (the corpus's format).
void write_hex(const std::string& path, const std::vector<uint8_t>& bytes) {
  std::ofstream out(path);
  for (size_t i = 0; i < bytes.size(); ++i) {
    char h[3];
    std::snprintf(h, sizeof h, "%02x", bytes[i]);
    out << h << ((i + 1) % 32 == 0 || i + 1 == bytes.size() ? "\n" : "");
  }
  if (!out) throw std::runtime_error("cannot write " + path);
}

struct RawWriter {
  RawWriter(farm::dds::Bus& bus, const char* topic, const std::string& type_name, const char* profile) : bus(bus) {
    fdds::Topic* t = bus.topic(topic, fdds::TypeSupport(new RawType(type_name, 64u << 20)));
    writer = bus.publisher()->create_datawriter(t, bus.writer_qos(topic, profile));
    if (!writer) throw std::runtime_error(std::string("cannot create a writer for ") + topic);
  }
  ~RawWriter() { bus.publisher()->delete_datawriter(writer); }
  int matched() const {
    fdds::PublicationMatchedStatus st;
    writer->get_publication_matched_status(st);
    return st.current_count;
  }
  farm::dds::Bus& bus;
  fdds::DataWriter* writer = nullptr;
  RawSample sample;
  uint64_t sent = 0;
};

}  // namespace

farm::msg::TransitionBatch one_step_batch(const std::string& experiment, const std::string& id, unsigned obs,
                                          unsigned act) {
  farm::msg::TransitionBatch b;
  b.experiment_id(experiment);
  b.worker_id(id);
  b.worker_session(1);
  b.num_steps(1);
  b.num_envs(1);
  b.obs_dim(obs);
  b.act_dim(act);
  b.observations(std::vector<float>(obs, 0.5f));
  b.actions(std::vector<float>(act, 0.f));
  b.rewards({0.f});
  b.terminated({0});
  b.truncated({0});
  b.log_probs({0.f});
  b.next_observations(std::vector<float>(obs, 0.5f));
  return b;
}

int send_malformed(farm::dds::Bus& bus, const std::string& id, const std::string& experiment, unsigned obs,
                   unsigned act, const std::string& kind, double seconds, uint64_t fuzz_seed,
                   const std::string& dump_dir) {
  using namespace farm::msg;
  if (kind != "bool" && kind != "length" && kind != "truncate" && kind != "fuzz")
    throw std::runtime_error("--malformed takes bool, length, truncate or fuzz, not '" + kind + "'");
  // Well-formed samples of the experiment, one per topic.
  TransitionBatch b = one_step_batch(experiment, id, obs, act);
  b.terminated({1});
  b.final_index({0});
  b.final_observations(std::vector<float>(obs, 0.5f));
  EpisodeSummary e;
  e.terminated(true);
  e.length(1);
  // For the length bomb, a megabyte after the episodes' count: a decoder that trusts the count
  // allocates an episode summary for each of those bytes.
  // (A dumped one, for the corpus, keeps 16 floats: the counts still claim every byte left.)
  if (kind == "length") e.metrics(std::vector<float>(dump_dir.empty() ? 1 << 18 : 16, 0.f));
  b.episodes({e});
  WorkerStatus st;
  st.worker_id(id);
  st.worker_session(1);
  st.host("intruder");
  st.experiment_id(experiment);
  st.state("running");
  EvaluationAnswer ans;
  ans.experiment_id(experiment);
  ans.worker_id(id);
  EvaluationEpisode ep;
  ep.terminated(true);
  ans.episodes({ep});
  ExperimentSpec spec;
  spec.experiment_id(experiment);
  spec.config_text("experiment_id: \"" + experiment + "\"");
  spec.obs_dim(obs);
  spec.act_dim(act);
  PolicyWeights w;
  w.experiment_id(experiment);
  w.version(1);
  w.layer_sizes({int32_t(obs), 4, int32_t(act)});
  w.parameters(std::vector<float>(obs * 4 + 4 + 4 * act + act, 0.f));
  EvaluationRequest q;
  q.experiment_id(experiment);
  q.worker_id("nobody-" + id);
  q.episodes(1);
  q.policy(w);

  struct Target {
    const char* topic;
    const char* profile;
    const farm::wire::Layout& layout;
    std::vector<uint8_t> bytes;
  };
  std::vector<Target> targets = {
      {farm::dds::kBatchTopic, "batch_writer", farm::wire::transition_batch(),
       serialized<TransitionBatch, TransitionBatchPubSubType>(b)},
      {farm::dds::kWorkerStatusTopic, "status_writer", farm::wire::worker_status(),
       serialized<WorkerStatus, WorkerStatusPubSubType>(st)},
      {farm::dds::kEvalAnswerTopic, "batch_writer", farm::wire::evaluation_answer(),
       serialized<EvaluationAnswer, EvaluationAnswerPubSubType>(ans)},
      {farm::dds::kSpecTopic, "latest_writer", farm::wire::experiment_spec(),
       serialized<ExperimentSpec, ExperimentSpecPubSubType>(spec)},
      {farm::dds::kWeightsTopic, "latest_writer", farm::wire::policy_weights(),
       serialized<PolicyWeights, PolicyWeightsPubSubType>(w)},
      {farm::dds::kEvalRequestTopic, "batch_writer", farm::wire::evaluation_request(),
       serialized<EvaluationRequest, EvaluationRequestPubSubType>(q)},
  };
  std::mt19937_64 rng(fuzz_seed);
  std::vector<std::unique_ptr<RawWriter>> writers;
  std::vector<const Target*> sources;  // each writer's well-formed sample (fuzz)
  for (Target& t : targets) {
    const std::vector<uint8_t> good = t.bytes;
    t.bytes = kind == "fuzz" ? fuzzed(good, t.layout, rng) : broken(t.bytes, t.layout, kind);
    if (t.bytes.empty()) continue;  // nothing of this kind to break in this type
    if (!dump_dir.empty()) {
      std::filesystem::create_directories(dump_dir);
      const std::string full = t.layout.name, type = full.substr(full.rfind(':') + 1);  // farm::msg::X -> X
      write_hex(dump_dir + "/" + type + "_" + kind + ".hex", t.bytes);
      continue;
    }
    try {
      writers.push_back(std::make_unique<RawWriter>(bus, t.topic, t.layout.name, t.profile));
    } catch (const std::runtime_error& e) {
      // Under security a certificate may write only its role's topics: the others are skipped.
      if (bus.security_dir().empty()) throw;
      std::printf("%s: not permitted to write %s: skipped\n", id.c_str(), t.topic);
      record("not_permitted", {{"topic", t.topic}});
      continue;
    }
    writers.back()->sample.bytes = t.bytes;
    t.bytes = good;
    sources.push_back(&t);
  }
  if (!dump_dir.empty()) return 0;
  const double t_match = farm::now_seconds();
  auto all_matched = [&] {
    for (const auto& w : writers)
      if (w->matched() == 0) return false;
    return true;
  };
  while (!all_matched() && farm::now_seconds() - t_match < 15)
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  for (const double t0 = farm::now_seconds(); farm::now_seconds() - t0 < seconds;) {
    for (size_t i = 0; i < writers.size(); ++i) {
      auto& w = writers[i];
      if (kind == "fuzz") w->sample.bytes = fuzzed(sources[i]->bytes, sources[i]->layout, rng);
      w->sent += w->writer->write(&w->sample);
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  for (auto& w : writers) w->writer->wait_for_acknowledgments(eprosima::fastrtps::Duration_t(2.0));
  std::printf("%s: malformed (%s, seed %llu) samples written:", id.c_str(), kind.c_str(),
              (unsigned long long)fuzz_seed);
  for (const auto& w : writers) {
    std::printf(" %s %llu (matched %d)", w->writer->get_topic()->get_name().c_str(), (unsigned long long)w->sent,
                w->matched());
    record("malformed", {{"kind", kind},
                         {"seed", fuzz_seed},
                         {"topic", w->writer->get_topic()->get_name()},
                         {"written", w->sent},
                         {"matched", w->matched()}});
  }
  std::printf("\n");
  std::fflush(stdout);
  return 0;
}
