// farm_intruder --malformed KIND: samples of every topic whose bytes are not a valid encoding of
// their type, written through a type that sends raw bytes under the farm's type names. Each starts
// as a well-formed sample of the experiment, serialized by the generated code, and is then broken
// one way (KIND):
//   bool      a boolean byte set to 2 (the types that have one)
//   length    every sequence's and string's count set to the number of bytes left in the sample
//             (the batch carries a megabyte of episode metrics, so that the counts claim a lot)
//   truncate  the sample cut after half its bytes
// To the learner: TransitionBatch, WorkerStatus, EvaluationAnswer; to the workers: ExperimentSpec,
// PolicyWeights, EvaluationRequest. One of each every 100 ms for --seconds once matched; it prints
// how many of each it wrote.
#include "intruder_malformed.h"

#include <cstdio>
#include <cstring>
#include <functional>
#include <memory>
#include <thread>
#include <vector>

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
                   unsigned act, const std::string& kind, double seconds) {
  using namespace farm::msg;
  if (kind != "bool" && kind != "length" && kind != "truncate")
    throw std::runtime_error("--malformed takes bool, length or truncate, not '" + kind + "'");
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
  if (kind == "length") e.metrics(std::vector<float>(1 << 18, 0.f));
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
  std::vector<std::unique_ptr<RawWriter>> writers;
  for (Target& t : targets) {
    t.bytes = broken(t.bytes, t.layout, kind);
    if (t.bytes.empty()) continue;  // nothing of this kind to break in this type
    writers.push_back(std::make_unique<RawWriter>(bus, t.topic, t.layout.name, t.profile));
    writers.back()->sample.bytes = t.bytes;
  }
  const double t_match = farm::now_seconds();
  auto all_matched = [&] {
    for (const auto& w : writers)
      if (w->matched() == 0) return false;
    return true;
  };
  while (!all_matched() && farm::now_seconds() - t_match < 15)
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  for (const double t0 = farm::now_seconds(); farm::now_seconds() - t0 < seconds;) {
    for (auto& w : writers) w->sent += w->writer->write(&w->sample);
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  for (auto& w : writers) w->writer->wait_for_acknowledgments(eprosima::fastrtps::Duration_t(2.0));
  std::printf("%s: malformed (%s) samples written:", id.c_str(), kind.c_str());
  for (const auto& w : writers)
    std::printf(" %s %llu (matched %d)", w->writer->get_topic()->get_name().c_str(), (unsigned long long)w->sent,
                w->matched());
  std::printf("\n");
  std::fflush(stdout);
  return 0;
}
