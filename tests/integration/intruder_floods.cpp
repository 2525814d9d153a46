// farm_intruder's floods (intruder_floods.h).
#include "intruder_floods.h"

#include <algorithm>
#include <cstdio>
#include <thread>
#include <vector>

#include "config.h"
#include "intruder_events.h"
#include "meter.h"

void make_oversized(farm::msg::TransitionBatch& b, std::mt19937_64& rng, const std::string& id, unsigned obs,
                    unsigned act) {
  const unsigned OT = farm::kMaxStepsPerBatch / 16, ON = farm::kMaxEnvsPerWorker;
  static_assert(farm::kMaxStepsPerBatch / 16 * farm::kMaxEnvsPerWorker <= farm::kMaxBatchTransitions);
  const size_t TN = size_t(OT) * ON;
  b.worker_session(rng());
  b.num_steps(OT);
  b.num_envs(ON);
  b.observations(std::vector<float>(TN * obs, 0.5f));
  b.actions(std::vector<float>(TN * act, 0.0f));
  b.rewards(std::vector<float>(TN, 0.0f));
  b.terminated(std::vector<uint8_t>(TN, 0));
  b.truncated(std::vector<uint8_t>(TN, 0));
  b.log_probs(std::vector<float>(TN, 0.0f));
  b.next_observations(std::vector<float>(size_t(ON) * obs, 0.5f));
  const size_t bytes = farm::msg::TransitionBatch::getCdrSerializedSize(b) + 4;
  std::printf("%s: oversized batches of %ux%u transitions, %zu bytes serialized\n", id.c_str(), OT, ON, bytes);
  std::fflush(stdout);
  record("serialized", {{"steps", OT}, {"envs", ON}, {"bytes", bytes}});
}

void send_oversized(BatchWriter& out, farm::msg::TransitionBatch& b, double t0, double seconds, uint64_t& sent,
                    int& max_matched) {
  while (farm::now_seconds() - t0 < seconds) {
    b.sequence_number(sent);
    if (out.write(b)) ++sent;
    max_matched = std::max(max_matched, out.matched());
    std::this_thread::sleep_for(std::chrono::milliseconds(500));
  }
}

void send_hostile(BatchWriter& out, farm::msg::TransitionBatch& b, std::mt19937_64& rng, double t0, double seconds,
                  uint64_t& sent, int& max_matched) {
  while (farm::now_seconds() - t0 < seconds) {
    b.worker_session(1);
    b.sequence_number(sent % 2 ? UINT64_MAX - sent : (uint64_t(1) << 63) + sent);
    sent += out.write(b);
    for (int k = 0; k < 50; ++k) {
      b.worker_session(rng());
      b.sequence_number(rng() | (uint64_t(1) << 40));
      sent += out.write(b);
    }
    max_matched = std::max(max_matched, out.matched());
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
}

int flood(farm::dds::Bus& bus, BatchWriter& out, farm::msg::TransitionBatch& b, std::mt19937_64& rng,
          const std::string& id, const std::string& experiment, const Flood& f, double t0, double seconds) {
  while (out.matched() == 0 && farm::now_seconds() - t0 < 15)
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  uint64_t batches = 0, beats = 0;
  for (unsigned k = 0; k < f.streams; ++k) {
    b.worker_id(id + "-" + std::to_string(k));
    b.worker_session(rng());
    b.sequence_number(0);
    batches += out.write(b);
  }
  if (f.heartbeats > 0) {
    farm::dds::Writer<farm::msg::WorkerStatus, farm::msg::WorkerStatusPubSubType> beat_out(
        bus, farm::dds::kWorkerStatusTopic, "status_writer");
    while (beat_out.matched() == 0 && farm::now_seconds() - t0 < 15)
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    farm::msg::WorkerStatus st;
    st.worker_id(id);
    st.host(f.host);
    st.experiment_id(experiment);
    st.envs(1);
    st.threads(1);
    st.state("running");
    std::vector<uint64_t> sessions(f.heartbeats);
    for (auto& s : sessions) s = rng();
    for (const double t_beat = farm::now_seconds();;) {
      for (uint64_t s : sessions) {
        st.worker_session(s);
        beats += beat_out.write(st);
      }
      if (f.beat_every <= 0 || farm::now_seconds() - t_beat + f.beat_every > seconds) break;
      std::this_thread::sleep_for(std::chrono::duration<double>(f.beat_every));
    }
  }
  std::printf("%s: flooded %llu batches of invented streams, %llu heartbeats of invented sessions\n", id.c_str(),
              (unsigned long long)batches, (unsigned long long)beats);
  std::fflush(stdout);
  record("flooded", {{"batches", batches}, {"heartbeats", beats}});
  if (f.beat_every <= 0) std::this_thread::sleep_for(std::chrono::duration<double>(seconds));
  return 0;
}

// --big-to-workers: one spec, weights and evaluation request of mib MiB each (see the top).
int big_to_workers(farm::dds::Bus& bus, const std::string& id, const std::string& experiment, unsigned mib,
                   double seconds) {
  using namespace farm::msg;
  farm::dds::Writer<ExperimentSpec, ExperimentSpecPubSubType> spec_out(bus, farm::dds::kSpecTopic, "latest_writer");
  farm::dds::Writer<PolicyWeights, PolicyWeightsPubSubType> weights_out(bus, farm::dds::kWeightsTopic, "latest_writer");
  farm::dds::Writer<EvaluationRequest, EvaluationRequestPubSubType> request_out(bus, farm::dds::kEvalRequestTopic,
                                                                                "batch_writer");
  const double t_match = farm::now_seconds();
  while ((spec_out.matched() == 0 || weights_out.matched() == 0 || request_out.matched() == 0) &&
         farm::now_seconds() - t_match < 15)
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  const size_t floats = size_t(mib) << 18;
  PolicyWeights w;
  w.experiment_id(experiment);
  w.version(1);
  w.layer_sizes({3, int32_t(floats / 4 - 1), 1});
  w.parameters(std::vector<float>(floats, 0.f));
  EvaluationRequest q;
  q.experiment_id(experiment);
  q.learner_session(77);
  q.request_id(1);
  q.worker_id("nobody-" + id);
  q.policy_version(1);
  q.episodes(1);
  q.policy(w);
  ExperimentSpec s;
  s.experiment_id(experiment);
  s.config_text(std::string(size_t(mib) << 20, '#'));
  s.learner_session(77);
  const int sent = int(spec_out.write(s)) + int(weights_out.write(w)) + int(request_out.write(q));
  std::printf("%s: sent %d samples of %u MiB to the workers\n", id.c_str(), sent, mib);
  std::fflush(stdout);
  record("big_sent", {{"samples", sent}, {"mib", mib}});
  std::this_thread::sleep_for(std::chrono::duration<double>(seconds));
  return 0;
}
