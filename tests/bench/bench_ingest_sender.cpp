// bench_ingest's sender mode (bench_ingest.h): one synthetic worker that publishes well-formed
// TransitionBatch samples of the config's task and batch shape at a fixed rate on the batch topic,
// with a worker's QoS, until SIGTERM, and then closes its stream as a worker does.
#include <signal.h>
#include <unistd.h>

#include <atomic>
#include <cstdio>
#include <functional>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "bench_ingest.h"
#include "task_specs.h"

namespace bench_ingest {

Shape shape_of(const std::string& config) {
  Shape s;
  s.cfg = farm::robots::load_config_file(config);
  s.spec = farm::robots::task_spec(s.cfg.task());
  s.steps = int(s.cfg.worker().steps_per_batch());
  s.envs = int(s.cfg.worker().envs_per_worker());
  return s;
}

namespace {

std::atomic<bool> g_stop{false};
void on_term(int) { g_stop = true; }

}  // namespace

// One well-formed batch of T steps x N envs: finite observations, actions in range, and env 0's
// episode ending (truncated) at the last step with its final observation and summary.
void fill_batch(const Shape& s, const std::string& experiment, const std::string& id, farm::msg::TransitionBatch& b) {
  const size_t T = s.steps, N = s.envs, od = s.spec.obs_dim, ad = s.spec.act_dim, TN = T * N;
  std::mt19937 rng(std::hash<std::string>()(id));
  std::normal_distribution<float> g(0.f, 0.5f);
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  b.experiment_id(experiment);
  b.worker_id(id);
  b.worker_session(uint64_t(getpid()) << 20 | (rng() & 0xfffff));
  b.num_steps(uint32_t(T));
  b.num_envs(uint32_t(N));
  b.obs_dim(uint32_t(od));
  b.act_dim(uint32_t(ad));
  std::vector<float> obs(TN * od), act(TN * ad), rew(TN), lp(TN), next(N * od), fin(od);
  for (float& v : obs) v = g(rng);
  for (float& v : act) v = s.spec.num_actions > 0 ? float(rng() % uint32_t(s.spec.num_actions)) : u(rng);
  for (float& v : rew) v = g(rng);
  for (float& v : lp) v = g(rng);
  for (float& v : next) v = g(rng);
  for (float& v : fin) v = g(rng);
  std::vector<uint8_t> term(TN, 0), trunc(TN, 0);
  trunc[(T - 1) * N] = 1;
  b.observations(obs);
  b.actions(act);
  b.rewards(rew);
  b.log_probs(lp);
  b.terminated(term);
  b.truncated(trunc);
  b.next_observations(next);
  b.final_index({uint32_t((T - 1) * N)});
  b.final_observations(fin);
  farm::msg::EpisodeSummary e;
  e.env(0);
  e.episode_return(-150.f);
  e.length(uint32_t(s.spec.max_episode_steps > 0 ? s.spec.max_episode_steps : T));
  e.metrics(std::vector<float>(s.spec.metric_names.size(), 0.f));
  b.episodes({e});
  b.end_of_stream(false);
}

int run_sender(const Options& o) {
  signal(SIGTERM, on_term);
  signal(SIGINT, on_term);
  const Shape s = shape_of(o.config);
  farm::dds::Bus bus(o.bus, "bench_ingest_" + o.id);
  farm::dds::Writer<farm::msg::TransitionBatch, farm::msg::TransitionBatchPubSubType> out(bus, farm::dds::kBatchTopic,
                                                                                          "batch_writer");
  farm::msg::TransitionBatch b;
  fill_batch(s, o.experiment, o.id, b);
  const auto t_match = Clock::now();
  while (out.matched() < 1 && !g_stop) {
    if (since(t_match) > 30) {
      std::fprintf(stderr, "sender %s: no learner-side reader matched within 30 s\n", o.id.c_str());
      return 1;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  // Paced at a fixed rate; a sender blocked by the reader's flow control falls behind the schedule
  // and does not burst to catch up by more than a quarter of a second.
  const double period = 1.0 / o.rate;
  auto next = Clock::now();
  uint64_t seq = 0, retries = 0;
  while (!g_stop) {
    std::this_thread::sleep_until(next);
    b.sequence_number(seq);
    // A write given up on at SIGTERM never sent its number, so the end of stream reuses it.
    bool written = false;
    while (!(written = out.write(b)) && !g_stop) ++retries;
    if (written) ++seq;
    next += std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(period));
    const auto floor = Clock::now() - std::chrono::milliseconds(250);
    if (next < floor) next = floor;
  }
  b.sequence_number(seq);
  b.end_of_stream(true);
  b.num_steps(0);
  for (auto* v :
       {&b.observations(), &b.actions(), &b.rewards(), &b.log_probs(), &b.next_observations(), &b.final_observations()})
    v->clear();
  b.terminated().clear();
  b.truncated().clear();
  b.final_index().clear();
  b.episodes().clear();
  for (int k = 0; k < 5 && !out.write(b); ++k) {
  }
  out.wait_for_acks(5);
  std::printf("sender %s: sent %llu batches, %llu blocked writes retried\n", o.id.c_str(), (unsigned long long)seq,
              (unsigned long long)retries);
  return 0;
}

}  // namespace bench_ingest
