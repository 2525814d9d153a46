// PPO as the learner runs it: the networks (ppo.h) over rollout storage (rollout_storage.h), fitted
// when the fit scheduler says a fit's steps or episodes are in (fit_scheduler.h): GAE, or V-trace
// for data of older versions in asynchronous mode.
#include "ppo_algorithm.h"

#include <ATen/CPUGeneratorImpl.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <map>
#include <mutex>
#include <random>

#include "fit_scheduler.h"
#include "meter.h"
#include "ppo.h"
#include "rng_state.h"
#include "rollout_storage.h"

namespace farm {

namespace fs = std::filesystem;

namespace {

FitPlan plan_of(const config::PpoConfig& c) {
  FitPlan p;
  p.steps_per_fit = c.steps_per_fit();
  p.episodes_per_fit = c.episodes_per_fit();
  p.steps_per_run = c.steps_per_run();
  p.episodes_per_run = c.episodes_per_run();
  return p;
}

std::string num(const char* f, double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, f, v);
  return buf;
}

class PpoAlgorithm final : public Algorithm {
 public:
  PpoAlgorithm(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec)
      : seed_(cfg.seed()),
        spec_(spec),
        pc_(cfg.ppo()),
        ppo_(pc_, spec.obs_dim, spec.act_dim, cfg.seed()),
        storage_(spec.obs_dim, spec.act_dim),
        sched_(plan_of(pc_)) {}

  std::string name() const override { return "ppo"; }
  std::string describe() const override {
    const auto& p = pc_;
    return std::string(p.mode() == "async" ? "asynchronous " : "") + "PPO (" + p.variant() + ") " +
           ppo_.export_policy(0).layout.describe() + " actor, " +
           (p.steps_per_fit() > 0 ? std::to_string(p.steps_per_fit()) + " steps"
                                  : std::to_string(p.episodes_per_fit()) + " episodes") +
           " per fit, max policy lag " + std::to_string(p.max_policy_lag()) +
           (p.surrogate() == "proximal" ? ", proximal surrogate" : "");
  }
  std::string warm_up() override {
    if (!pc_.warm_up() || !ppo_.device().is_cuda()) return "";
    const double s = ppo_warm_up(pc_, spec_.obs_dim, spec_.act_dim, seed_, ppo_.device().str());
    return "warm-up on " + ppo_.device().str() + ": one fit of a throwaway copy on synthetic steps, " + num("%.2f", s) +
           " s, before the run starts (ppo.warm_up)";
  }

  void insert(const Batch& b) override {
    const Transitions& rows = *b.rows;
    storage_.add(b.num_steps, b.num_envs, rows.obs.data(), rows.actions.data(), rows.rewards.data(),
                 rows.terminated.data(), b.truncated, b.log_probs, rows.next_obs.data(), b.policy_version);
    sched_.on_data(rows.n, int64_t(b.episodes->size()));
  }
  Holding holding() const override {
    Holding h;
    h.rows = storage_.steps();
    h.capacity = pc_.steps_per_fit();
    h.steps_wanted = sched_.steps_wanted();
    h.episodes_wanted = pc_.episodes_per_fit() > 0 ? sched_.episodes_wanted() : -1;
    if (sched_.run_done()) {
      h.run_done = pc_.steps_per_run() > 0 && sched_.run_steps() >= pc_.steps_per_run()
                       ? "run length " + std::to_string(pc_.steps_per_run()) + " steps"
                       : "run length " + std::to_string(pc_.episodes_per_run()) + " episodes";
    }
    return h;
  }
  int64_t ready() const override { return sched_.fit_due() ? 1 : 0; }

  // One fit per update asked, of the steps the scheduler hands it: a fit's, or at a stop what is held.
  std::vector<UpdateFigures> update(int n, uint64_t version) override {
    std::vector<UpdateFigures> out;
    for (int k = 0; k < n && sched_.fit_steps() > 0; ++k) {
      const FitScheduler::Fit f = sched_.take_fit();
      PpoSamples samples;
      RolloutStorage::VTrace vtrace;
      vtrace.log_prob = [this](const float* o, const float* a, int64_t m) { return ppo_.log_probs(o, a, m); };
      vtrace.rho_bar = pc_.vtrace_rho_bar();
      vtrace.c_bar = pc_.vtrace_c_bar();
      UpdateFigures u;
      storage_.take(
          f.steps_used, [this](const float* o, int64_t m) { return ppo_.values(o, m); }, pc_.gamma(), pc_.gae_lambda(),
          version, samples, pc_.mode() == "async" ? &vtrace : nullptr, &u.steps_by_version);
      const PpoStats st = ppo_.fit(samples);
      // The normalizer moves between versions only, so a version is one fixed policy.
      if (pc_.normalize_observations()) ppo_.normalizer().update(samples.obs.data(), samples.n);
      u.update = ppo_.fits();
      u.values = {
          {"value loss", st.value_loss},        {"policy loss", st.policy_loss},           {"kl", st.kl},
          {"learning rate", st.learning_rate},  {"clip fraction", st.clip_fraction},       {"entropy", st.entropy},
          {"steps used", double(f.steps_used)}, {"steps carried", double(f.steps_carried)}};
      out.push_back(std::move(u));
    }
    return out;
  }
  int64_t updates() const override { return ppo_.updates(); }
  int64_t forget_older_than(uint64_t oldest) override {
    const int64_t dropped = storage_.drop_older_than(oldest);
    sched_.forget(dropped);
    return dropped;
  }

  PolicyParams policy(uint64_t version) const override { return ppo_.export_policy(version); }
  void save_networks(const std::string& dir) const override {
    fs::create_directories(fs::path(dir) / "ppo");
    ppo_.save((fs::path(dir) / "ppo").string());
  }
  void load_networks(const std::string& dir) override { ppo_.load((fs::path(dir) / "ppo").string()); }
  // A checkpoint holds the steps accepted and not yet fitted too, so a resume loses none of them.
  void save(const std::string& dir) const override {
    save_networks(dir);
    storage_.save(rollout_file(dir));
  }
  // A checkpoint without the file (written before it was kept) resumes with none held.
  void load(const std::string& dir) override {
    load_networks(dir);
    if (fs::exists(rollout_file(dir))) storage_.load(rollout_file(dir));
  }
  void to_manifest(config::CheckpointManifest& m) const override {
    m.set_run_steps(uint64_t(sched_.run_steps()));
    m.set_fit_episodes(uint64_t(sched_.fit_episodes()));
    rng_to_manifest(nullptr, m);
  }
  // The run's counters go on from where they were, with the stored steps toward the next fit; the
  // steps keep their lag to the version the resumed learner publishes the same networks as.
  std::string from_manifest(const config::CheckpointManifest& m) override {
    rng_from_manifest(m, nullptr);
    if (m.has_resumed_version() && m.resumed_version() > m.policy_version())
      storage_.shift_versions(m.resumed_version() - m.policy_version());
    sched_.restore_run(int64_t(m.run_steps()), int64_t(m.episodes()), ppo_.fits(), storage_.steps(),
                       int64_t(m.fit_episodes()));
    return std::to_string(ppo_.fits()) + " fits, learning rate " + num("%.3g", ppo_.learning_rate()) + ", " +
           std::to_string(storage_.steps()) + " steps held toward the next fit";
  }

 private:
  static std::string rollout_file(const std::string& dir) { return (fs::path(dir) / "rollouts.bin").string(); }

  const uint64_t seed_;
  const robots::TaskSpec spec_;
  const config::PpoConfig pc_;
  Ppo ppo_;
  RolloutStorage storage_;
  FitScheduler sched_;
};

}  // namespace

double ppo_warm_up(const config::PpoConfig& pc_in, int obs_dim, int act_dim, uint64_t seed, const std::string& device) {
  const double t = now_seconds();
  auto gen = at::detail::getDefaultCPUGenerator();
  torch::Tensor cpu_state;
  {
    std::lock_guard<std::mutex> lock(gen.mutex());
    cpu_state = gen.get_state();
  }
  {
    config::PpoConfig pc = pc_in;
    pc.set_device(device);  // resolved: "auto" is said once, by the run's own networks
    Ppo ppo(pc, obs_dim, act_dim, seed);
    RolloutStorage storage(obs_dim, act_dim);
    const int T = 24, N = 64;  // a batch's shape; the fit's shapes are what matter
    const int64_t steps = pc.steps_per_fit() > 0 ? pc.steps_per_fit() : int64_t(T) * N;
    const uint64_t lag = uint64_t(std::max(0, pc.max_policy_lag()));
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<float> u(-1.0f, 1.0f);
    std::vector<float> obs(size_t(T) * N * obs_dim), next(obs.size()), act(size_t(T) * N * act_dim);
    std::vector<float> rew(size_t(T) * N);
    std::vector<uint8_t> term(rew.size(), 0), trunc(rew.size(), 0);
    for (int64_t added = 0, b = 0; added < steps; added += int64_t(T) * N, ++b) {
      for (auto* v : {&obs, &next, &act, &rew})
        for (float& x : *v) x = u(rng);
      term.assign(term.size(), 0);
      term[size_t(b) % term.size()] = 1;  // an episode ends in each batch
      const std::vector<float> lp = ppo.log_probs(obs.data(), act.data(), int64_t(T) * N);
      storage.add(T, N, obs.data(), act.data(), rew.data(), term.data(), trunc.data(), lp.data(), next.data(),
                  uint64_t(b) % (lag + 1));
    }
    RolloutStorage::VTrace vtrace;
    vtrace.log_prob = [&ppo](const float* o, const float* a, int64_t n) { return ppo.log_probs(o, a, n); };
    vtrace.rho_bar = pc.vtrace_rho_bar();
    vtrace.c_bar = pc.vtrace_c_bar();
    PpoSamples samples;
    storage.take(
        std::min(steps, storage.steps()), [&ppo](const float* o, int64_t n) { return ppo.values(o, n); }, pc.gamma(),
        pc.gae_lambda(), lag, samples, pc.mode() == "async" ? &vtrace : nullptr);
    ppo.fit(samples);
    (void)ppo.export_policy(1);
  }
  std::lock_guard<std::mutex> lock(gen.mutex());
  gen.set_state(cpu_state);
  return now_seconds() - t;
}

std::unique_ptr<Algorithm> make_ppo(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec) {
  if (spec.num_actions > 0)
    throw std::invalid_argument("algorithm \"ppo\" needs continuous actions; task '" + cfg.task().name() +
                                "' has discrete ones");
  return std::make_unique<PpoAlgorithm>(cfg, spec);
}

}  // namespace farm
