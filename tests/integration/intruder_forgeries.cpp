// farm_intruder's forgeries (intruder_forgeries.h).
#include "intruder_forgeries.h"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cstdio>
#include <map>
#include <memory>
#include <thread>
#include <vector>

#include "intruder_events.h"
#include "intruder_malformed.h"
#include "meter.h"

namespace {

// One round of --eval-requests: six requests to `worker`, each wrong in one way, and one a pendulum
// worker could run; returns how many were written.
int send_bad_eval_requests(farm::dds::Writer<farm::msg::EvaluationRequest, farm::msg::EvaluationRequestPubSubType>& out,
                           const std::string& experiment, const std::string& worker, uint64_t& next_id) {
  const int big = 2147483647;
  farm::msg::PolicyWeights good;
  good.experiment_id(experiment);
  good.version(5);
  good.layer_sizes({3, 4, 2});
  good.parameters(std::vector<float>(3 * 4 + 4 + 4 * 2 + 2, 0.f));
  const auto request = [&](uint32_t episodes, uint32_t first, const farm::msg::PolicyWeights& policy) {
    farm::msg::EvaluationRequest q;
    q.experiment_id(experiment);
    q.learner_session(77);
    q.request_id(++next_id);
    q.worker_id(worker);
    q.policy_version(5);
    q.episodes(episodes);
    q.first_episode(first);
    q.seed(1);
    q.policy(policy);
    const int written = int(out.write(q));
    // Apart in time: a worker keeps the last few requests addressed to it until its loop checks them.
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    return written;
  };
  farm::msg::PolicyWeights other = good, versioned = good, wrapped = good;
  other.experiment_id("another_experiment");
  versioned.version(6);
  wrapped.layer_sizes({3, big, big, big, big, big - 2, 1, 536870915, 2});
  wrapped.parameters(std::vector<float>(8, 0.f));
  return request(0, 0, good) + request(UINT32_MAX, 0, good) + request(1, UINT32_MAX, good) + request(1, 0, other) +
         request(1, 0, versioned) + request(1, 0, wrapped) + request(1, 0, good);
}

// The SPDP message a participant sends as it leaves (Fast DDS 2.9's form), in the name of the
// participant of `prefix`: a DATA(p[UD]) of the SPDP writer with the key hash and status disposed
// and unregistered inline, and the participant's GUID as the key. Little-endian throughout.
std::vector<uint8_t> participant_removal(const eprosima::fastrtps::rtps::GuidPrefix_t& prefix, uint32_t seq) {
  std::vector<uint8_t> m = {'R', 'T', 'P', 'S', 2, 3, 0x01, 0x0f};
  m.insert(m.end(), prefix.value, prefix.value + 12);
  const auto put16 = [&m](uint16_t v) { m.insert(m.end(), {uint8_t(v), uint8_t(v >> 8)}); };
  const auto put32 = [&m](uint32_t v) {
    m.insert(m.end(), {uint8_t(v), uint8_t(v >> 8), uint8_t(v >> 16), uint8_t(v >> 24)});
  };
  const auto guid = [&] {
    m.insert(m.end(), prefix.value, prefix.value + 12);
    m.insert(m.end(), {0x00, 0x00, 0x01, 0xc1});
  };
  m.insert(m.end(), {0x15, 0x0b});  // DATA, flags E | Q | K
  const size_t len_at = m.size();
  put16(0);
  put16(0);                                     // extra flags
  put16(16);                                    // octets to inline QoS
  m.insert(m.end(), {0x00, 0x01, 0x00, 0xc7});  // SPDP reader
  m.insert(m.end(), {0x00, 0x01, 0x00, 0xc2});  // SPDP writer
  put32(0);
  put32(seq);
  put16(0x0070);  // PID_KEY_HASH
  put16(16);
  guid();
  put16(0x0071);  // PID_STATUS_INFO: disposed | unregistered
  put16(4);
  m.insert(m.end(), {0, 0, 0, 3});
  put16(0x0001);  // PID_SENTINEL
  put16(0);
  m.insert(m.end(), {0x00, 0x03, 0x00, 0x00});  // PL_CDR_LE
  put16(0x0050);                                // PID_PARTICIPANT_GUID
  put16(16);
  guid();
  put16(0x0001);
  put16(0);
  const size_t len = m.size() - len_at - 2;
  m[len_at] = uint8_t(len);
  m[len_at + 1] = uint8_t(len >> 8);
  return m;
}

}  // namespace

int forge_answers(farm::dds::Bus& bus, const std::string& id, const std::string& experiment, double seconds,
                  float forged_return, uint32_t length, uint32_t metrics, bool own_heartbeat, unsigned obs,
                  unsigned act, bool deliver) {
  using namespace farm::msg;
  farm::dds::Reader<EvaluationRequest, EvaluationRequestPubSubType> requests(bus, farm::dds::kEvalRequestTopic,
                                                                             "batch_reader");
  // Another worker's session is read off its heartbeats; as a worker of its own (own_heartbeat,
  // which a worker certificate allows: it may not read heartbeats) it beats as session 1.
  std::unique_ptr<farm::dds::Reader<WorkerStatus, WorkerStatusPubSubType>> status;
  std::unique_ptr<farm::dds::Writer<WorkerStatus, WorkerStatusPubSubType>> beats;
  // As a worker of its own it also delivers well-formed batches, as a worker whose evaluations the
  // learner asks must have (unless deliver is false: it only beats under the id and answers).
  std::unique_ptr<farm::dds::Writer<TransitionBatch, TransitionBatchPubSubType>> batches;
  TransitionBatch b = one_step_batch(experiment, id, obs, act);
  if (own_heartbeat) {
    beats = std::make_unique<farm::dds::Writer<WorkerStatus, WorkerStatusPubSubType>>(
        bus, farm::dds::kWorkerStatusTopic, "status_writer");
    if (deliver)
      batches = std::make_unique<farm::dds::Writer<TransitionBatch, TransitionBatchPubSubType>>(
          bus, farm::dds::kBatchTopic, "batch_writer");
  } else {
    status = std::make_unique<farm::dds::Reader<WorkerStatus, WorkerStatusPubSubType>>(
        bus, farm::dds::kWorkerStatusTopic, "status_reader");
  }
  farm::dds::Writer<EvaluationAnswer, EvaluationAnswerPubSubType> answers(bus, farm::dds::kEvalAnswerTopic,
                                                                          "batch_writer");
  std::map<std::string, uint64_t> sessions;  // worker id -> its last heartbeat's session
  sessions[id] = 1;
  uint64_t answered = 0;
  const double t0 = farm::now_seconds();
  double beat_at = 0;
  while (farm::now_seconds() - t0 < seconds) {
    WorkerStatus st;
    while (status && status->take(st)) sessions[st.worker_id()] = st.worker_session();
    if (beats && farm::now_seconds() - beat_at >= 0.5) {
      st.worker_id(id);
      st.worker_session(1);
      st.host(farm::dds::hostname());
      st.experiment_id(experiment);
      st.envs(4);
      st.threads(1);
      st.state("running");
      beats->write(st);
      if (batches && batches->matched() > 0 && batches->write(b)) b.sequence_number(b.sequence_number() + 1);
      beat_at = farm::now_seconds();
    }
    EvaluationRequest q;
    while (requests.take(q)) {
      if (q.experiment_id() != experiment || (own_heartbeat && q.worker_id() != id)) continue;
      EvaluationAnswer a;
      a.experiment_id(q.experiment_id());
      a.learner_session(q.learner_session());
      a.request_id(q.request_id());
      a.worker_id(q.worker_id());
      a.worker_session(sessions[q.worker_id()]);
      a.policy_version(q.policy_version());
      a.seconds(0.01);
      std::vector<EvaluationEpisode> eps(q.episodes());
      for (auto& e : eps) {
        e.episode_return(forged_return);
        e.length(length);
        e.metrics(std::vector<float>(metrics, 1.f));
      }
      a.episodes(eps);
      answered += answers.write(a);
    }
    requests.wait(0.005);
  }
  std::printf("%s: forged %llu evaluation answers\n", id.c_str(), (unsigned long long)answered);
  record("forged_answers", {{"count", answered}});
  return 0;
}

int bad_eval_requests(farm::dds::Bus& bus, const std::string& id, const std::string& experiment,
                      const std::string& worker, double seconds) {
  farm::dds::Writer<farm::msg::EvaluationRequest, farm::msg::EvaluationRequestPubSubType> requests(
      bus, farm::dds::kEvalRequestTopic, "batch_writer");
  // The answers to its requests (they name its learner session, 77), counted.
  unsigned answers = 0;
  farm::dds::Reader<farm::msg::EvaluationAnswer, farm::msg::EvaluationAnswerPubSubType> answers_in(
      bus, farm::dds::kEvalAnswerTopic, "batch_reader");
  const auto count_answers = [&] {
    farm::msg::EvaluationAnswer a;
    while (answers_in.take(a)) answers += a.learner_session() == 77;
  };
  const double t_match = farm::now_seconds();
  while (requests.matched() == 0 && farm::now_seconds() - t_match < 15)
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  const double t0 = farm::now_seconds();  // --seconds of requests once matched
  uint64_t next_id = 0, sent = 0;
  while (farm::now_seconds() - t0 < seconds) {
    sent += send_bad_eval_requests(requests, experiment, worker, next_id);
    count_answers();
  }
  for (const double t1 = farm::now_seconds(); farm::now_seconds() - t1 < 2;) {  // the last ones' answers
    answers_in.wait(0.1);
    count_answers();
  }
  std::printf("%s: sent %llu evaluation requests to %s, readers matched %d, answers received %u\n", id.c_str(),
              (unsigned long long)sent, worker.c_str(), requests.matched(), answers);
  record("eval_requests",
         {{"worker", worker}, {"sent", sent}, {"readers_matched", requests.matched()}, {"answers_received", answers}});
  return 0;
}

int forge_removal(farm::dds::Bus& bus, const std::string& id, const std::string& experiment, double seconds,
                  double every_ms) {
  farm::dds::Reader<farm::msg::ExperimentSpec, farm::msg::ExperimentSpecPubSubType> spec(bus, farm::dds::kSpecTopic,
                                                                                         "latest_reader");
  eprosima::fastrtps::rtps::GuidPrefix_t learner;
  bool found = false;
  for (const double t0 = farm::now_seconds(); !found && farm::now_seconds() - t0 < 15;) {
    spec.wait(0.2);
    farm::msg::ExperimentSpec s;
    eprosima::fastdds::dds::SampleInfo info;
    while (spec.take(s, info))
      if (s.experiment_id() == experiment) {
        learner = info.sample_identity.writer_guid().guidPrefix;
        found = true;
      }
  }
  if (!found) {
    std::printf("%s: no spec of experiment '%s' in 15 s: no learner to name\n", id.c_str(), experiment.c_str());
    record("no_learner", {{"experiment_id", experiment}});
    return 4;
  }
  const int fd = ::socket(AF_INET, SOCK_DGRAM, 0);
  if (fd < 0) throw std::runtime_error("cannot open a UDP socket");
  const unsigned char loop = 1;
  ::setsockopt(fd, IPPROTO_IP, IP_MULTICAST_LOOP, &loop, sizeof loop);
  const uint32_t base = 7400 + 250 * uint32_t(bus.domain());
  std::vector<sockaddr_in> to;
  const auto add = [&to](const char* ip, uint32_t port) {
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_port = htons(uint16_t(port));
    ::inet_pton(AF_INET, ip, &a.sin_addr);
    to.push_back(a);
  };
  add("239.255.0.1", base);                                                // discovery multicast
  for (uint32_t p = 0; p < 120; ++p) add("127.0.0.1", base + 10 + 2 * p);  // metatraffic unicast
  char hex[40] = "";
  for (int k = 0; k < 12; ++k) std::snprintf(hex + 2 * k, 3, "%02x", learner.value[k]);
  std::printf("%s: naming learner %s in participant removals\n", id.c_str(), hex);
  std::fflush(stdout);
  record("naming_learner", {{"learner", std::string(hex)}});
  uint64_t sent = 0;
  uint32_t seq = 1000;
  for (const double t0 = farm::now_seconds(); farm::now_seconds() - t0 < seconds;) {
    const std::vector<uint8_t> m = participant_removal(learner, ++seq);
    for (const sockaddr_in& a : to)
      sent += ::sendto(fd, m.data(), m.size(), 0, reinterpret_cast<const sockaddr*>(&a), sizeof a) == ssize_t(m.size());
    std::this_thread::sleep_for(std::chrono::duration<double, std::milli>(every_ms));
  }
  ::close(fd);
  std::printf("%s: sent %llu participant removals in the learner's name\n", id.c_str(), (unsigned long long)sent);
  record("removals", {{"sent", sent}, {"learner", std::string(hex)}});
  return 0;
}

// --steal-streams: batches under every worker session heard of, numbered from 0, every 50 ms.
int steal_streams(farm::dds::Bus& bus, const std::string& id, const std::string& experiment, double seconds,
                  unsigned obs, unsigned act) {
  farm::dds::Reader<farm::msg::WorkerStatus, farm::msg::WorkerStatusPubSubType> beats(
      bus, farm::dds::kWorkerStatusTopic, "status_reader");
  farm::dds::Writer<farm::msg::TransitionBatch, farm::msg::TransitionBatchPubSubType> out(bus, farm::dds::kBatchTopic,
                                                                                          "batch_writer");
  std::map<std::pair<std::string, uint64_t>, uint64_t> next;  // (worker id, session) -> next sequence number
  uint64_t sent = 0;
  for (const double t0 = farm::now_seconds(); farm::now_seconds() - t0 < seconds;) {
    farm::msg::WorkerStatus st;
    while (beats.take(st))
      if (st.experiment_id() == experiment && st.worker_id() != id && next.size() < 16 &&
          next.emplace(std::make_pair(st.worker_id(), st.worker_session()), 0).second) {
        std::printf("%s: stealing the stream of %s session %llu\n", id.c_str(), st.worker_id().c_str(),
                    (unsigned long long)st.worker_session());
        std::fflush(stdout);
        record("stealing", {{"worker_id", st.worker_id()}, {"session", st.worker_session()}});
      }
    for (auto& [stream, seq] : next) {
      farm::msg::TransitionBatch b = one_step_batch(experiment, stream.first, obs, act);
      b.worker_session(stream.second);
      b.sequence_number(seq);
      if (out.write(b)) {
        ++seq;
        ++sent;
      }
    }
    beats.wait(0.05);
  }
  std::printf("%s: sent %llu batches under %zu worker sessions not its own\n", id.c_str(), (unsigned long long)sent,
              next.size());
  record("stolen", {{"batches", sent}, {"sessions", next.size()}});
  return 0;
}

// The experiment's weights as its learner publishes them, each written again under a version a
// million ahead: a worker that ran them would send batches of a version no learner published.
int forge_weights(farm::dds::Bus& bus, const std::string& id, const std::string& experiment, double seconds) {
  using farm::msg::PolicyWeights;
  farm::dds::Reader<PolicyWeights, farm::msg::PolicyWeightsPubSubType> in(bus, farm::dds::kWeightsTopic,
                                                                          "latest_reader");
  farm::dds::Writer<PolicyWeights, farm::msg::PolicyWeightsPubSubType> out(bus, farm::dds::kWeightsTopic,
                                                                           "latest_writer");
  constexpr uint64_t kAhead = 1000000;
  unsigned forged = 0;
  for (const double t0 = farm::now_seconds(); farm::now_seconds() - t0 < seconds;) {
    PolicyWeights w;
    while (in.take(w)) {
      if (w.experiment_id() != experiment || w.version() >= kAhead) continue;  // its own come back too
      w.version(w.version() + kAhead);
      forged += out.write(w);
    }
    in.wait(0.1);
  }
  std::printf("%s: forged %u weights, readers matched %d\n", id.c_str(), forged, out.matched());
  record("forged_weights", {{"count", forged}, {"readers_matched", out.matched()}});
  return 0;
}
