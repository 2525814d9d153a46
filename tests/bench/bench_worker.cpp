// Worker throughput against the physics alone: how much of raw mj_step speed survives policy
// inference, batching and threading.
//   bench_worker [--task NAME | --config FILE] [--envs N] [--threads K] [--seconds S] [--raw-only | --env-only]
// The limit is mj_step alone on the task's own simulations over states its episodes visit: the
// worker's envs as the task makes them (each its own mjData, and its own mjModel where the task
// randomizes dynamics), the visited states dealt to them round-robin, each restored with the
// controls the task had set and stepped the physics steps of one env step; in env steps/s (the
// physics steps per env step are measured from the simulated time one env step advances). Beside
// it the older figure, one resting state in one mjData stepped on and on: it keeps one simulation
// hot in the cache and meets only settled contacts, so a worker set against it loses to the cache
// misses of its envs and the physics of its states as much as to its own overhead.
// --raw-only measures only K loops at once and prints each loop's limit and their mean, both
// limits (tests/bench/bench_worker_farm.sh sets a farm's workers against the visited-state one).
// The policy is the config's actor where --config names a PPO or SAC config (hidden sizes,
// activation, head), else a 64-64 relu actor. --inference-only measures only policy inference:
// rows/s for calls of 1, 8 and 64 rows and of --envs rows (FARM_MLP_ISA=baseline forces the
// kernel's baseline path, see common/mlp.h).
// --env-only measures only the envs, without a policy: the farm::VecEnv that farm.make_vec steps, of
// the task as farm.make_vec makes it, stepped from C++ as farm.make_vec's pool steps it
// (tests/bench/bench_python_vec.py sets the Python loop against this one).
// --against FILE sets the worker on --config's task beside a worker on FILE's task, with the same
// envs, threads and policy sizes, measured in turn (twice each, the mean), and prints the ratio:
//   bench_worker --config deploy/configs/a1_terms_ppo.txtpb --against deploy/configs/a1_ppo.txtpb
#include <mujoco/mujoco.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <functional>
#include <memory>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "bench_options.h"
#include "config.h"
#include "mlp.h"
#include "rollout.h"
#include "task.h"
#include "task_specs.h"
#include "vec_env.h"

namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

// A state of the task after a few env steps with zero actions, and the physics steps the task
// runs per env step there.
struct RawStart {
  mjData* data = nullptr;
  double physics_per_env_step = 1;
};

RawStart raw_start(const farm::robots::Task& task) {
  const mjModel* m = task.model();
  auto s = task.make_state();
  std::vector<float> obs(task.spec().obs_dim), act(task.spec().act_dim, 0.f);
  task.reset(*s, 1, obs.data());
  const double t0 = s->data->time;
  int k = 0;
  for (; k < 10; ++k) {
    const auto r = task.step(*s, act.data(), obs.data());
    if (r.terminated || r.truncated) break;
  }
  RawStart out;
  if (k > 0) out.physics_per_env_step = std::max(1.0, (s->data->time - t0) / m->opt.timestep / k);
  out.data = mj_copyData(nullptr, m, s->data);
  return out;
}

// States the task's own episodes visit, driven by Gaussian actions of standard deviation
// `action_std` (a policy's exploration before it has learned; uniform action indices for a task
// with discrete actions), sampled every env step, each episode restarted where it ends. A record is
// the state at the end of an env step (positions, velocities, actuator activations, the controls the
// task set last, the solver's warm start): what mj_step meets in training, where one resting state
// meets only its own settled contacts.
constexpr int kVisitedSteps = 200;               // env steps recorded per episode, at most
constexpr int kVisitedEpisodes = 8;              // episodes recorded (fewer where the worker has fewer envs)
constexpr double kVisitedPhysicsSteps = 320000;  // physics steps recorded in all, at most

struct VisitedStates {
  int episodes = 0, steps_per_episode = 0;
  int nq = 0, nv = 0, na = 0, nu = 0;
  std::vector<double> time, qpos, qvel, act, ctrl, warm;
  size_t size() const { return time.size(); }
};

// For a worker of `envs` envs: kVisitedEpisodes episodes (fewer where it has fewer envs) of
// kVisitedSteps env steps, fewer for a task whose env step runs many physics steps (the mCLARI
// microbot's 500), at least 10.
VisitedStates visited_states(const farm::robots::Task& task, int envs, double physics_per_env_step, double action_std) {
  const int episodes = std::min(envs, kVisitedEpisodes);
  const int env_steps =
      std::max(10, std::min(kVisitedSteps, int(kVisitedPhysicsSteps / (physics_per_env_step * episodes))));
  const mjModel* m = task.model();
  VisitedStates v;
  v.episodes = episodes, v.steps_per_episode = env_steps;
  v.nq = m->nq, v.nv = m->nv, v.na = m->na, v.nu = m->nu;
  const auto& spec = task.spec();
  std::vector<float> obs(spec.obs_dim), act(spec.act_dim);
  std::mt19937_64 rng(7);
  std::normal_distribution<float> noise(0.f, float(action_std));
  for (int e = 0; e < episodes; ++e) {
    auto s = task.make_state();
    uint64_t episode = 1000 * uint64_t(e) + 1;
    task.reset(*s, episode, obs.data());
    for (int k = 0; k < env_steps; ++k) {
      if (spec.num_actions > 0) {  // a discrete task takes an action index
        act[0] = float(std::uniform_int_distribution<int>(0, spec.num_actions - 1)(rng));
      } else {
        for (auto& a : act) a = std::clamp(noise(rng), -1.f, 1.f);
      }
      const auto r = task.step(*s, act.data(), obs.data());
      const mjData* d = s->data;
      v.time.push_back(d->time);
      v.qpos.insert(v.qpos.end(), d->qpos, d->qpos + m->nq);
      v.qvel.insert(v.qvel.end(), d->qvel, d->qvel + m->nv);
      v.act.insert(v.act.end(), d->act, d->act + m->na);
      v.ctrl.insert(v.ctrl.end(), d->ctrl, d->ctrl + m->nu);
      v.warm.insert(v.warm.end(), d->qacc_warmstart, d->qacc_warmstart + m->nv);
      if (r.terminated || r.truncated) task.reset(*s, ++episode, obs.data());
    }
  }
  return v;
}

// mj_step over the visited states: each state restored into one mjData, then the physics steps of
// one env step with the controls it had. Physics steps per second, restoring not counted.
double visited_steps_per_second(const farm::robots::Task& task, const VisitedStates& v, int copies, int per,
                                double seconds) {
  // `copies` simulations as the task makes them (a worker's envs: each its own mjData and, where
  // the task randomizes dynamics, its own mjModel), the visited states dealt round-robin to them.
  std::vector<std::unique_ptr<farm::robots::TaskState>> sims;
  for (int c = 0; c < copies; ++c) sims.push_back(task.make_state());
  uint64_t steps = 0;
  double stepping = 0;
  const auto t0 = Clock::now();
  size_t i = 0;
  while (seconds_since(t0) < seconds) {
    for (int n = 0; n < 200; ++n, i = (i + 1) % v.size()) {
      farm::robots::TaskState& sim = *sims[i % sims.size()];
      const mjModel* m = task.model_of(sim);
      mjData* d = sim.data;
      d->time = v.time[i];
      mju_copy(d->qpos, v.qpos.data() + i * v.nq, v.nq);
      mju_copy(d->qvel, v.qvel.data() + i * v.nv, v.nv);
      if (v.na) mju_copy(d->act, v.act.data() + i * v.na, v.na);
      if (v.nu) mju_copy(d->ctrl, v.ctrl.data() + i * v.nu, v.nu);
      mju_copy(d->qacc_warmstart, v.warm.data() + i * v.nv, v.nv);
      const auto s0 = Clock::now();
      for (int k = 0; k < per; ++k) mj_step(m, d);
      stepping += seconds_since(s0);
      steps += per;
    }
  }
  return double(steps) / stepping;
}

double raw_steps_per_second(const mjModel* m, const mjData* start, double seconds) {
  mjData* d = mj_copyData(nullptr, m, start);
  uint64_t steps = 0;
  const auto t0 = Clock::now();
  double elapsed = 0;
  do {
    for (int i = 0; i < 10000; ++i) mj_step(m, d);
    steps += 10000;
    elapsed = seconds_since(t0);
  } while (elapsed < seconds);
  mj_deleteData(d);
  return double(steps) / elapsed;
}

// The same loop on `threads` threads at once: what the hardware gives in parallel (shared
// cores, turbo limits), so the worker's scaling can be told apart from the machine's. Each loop's
// steps/s.
// `loop` on `threads` threads at once, each one's result.
std::vector<double> on_threads(int threads, const std::function<double()>& loop) {
  std::vector<double> rates(threads);
  std::vector<std::thread> pool;
  for (int k = 0; k < threads; ++k) pool.emplace_back([&, k] { rates[k] = loop(); });
  for (auto& t : pool) t.join();
  return rates;
}

std::vector<double> raw_parallel_loops(const mjModel* m, const mjData* start, int threads, double seconds) {
  return on_threads(threads, [&] { return raw_steps_per_second(m, start, seconds); });
}

double raw_parallel_steps_per_second(const mjModel* m, const mjData* start, int threads, double seconds) {
  double total = 0;
  for (double r : raw_parallel_loops(m, start, threads, seconds)) total += r;
  return total;
}

double worker_steps_per_second(std::shared_ptr<const farm::robots::Task> task, const farm::PolicyParams& policy,
                               int envs, int threads, int T, double seconds) {
  farm::Rollout rollout(std::move(task), envs, threads, 1);
  rollout.set_policy(policy);
  farm::RolloutBatch batch;
  rollout.collect(T, batch);  // warm-up: sizes every buffer
  const uint64_t start_steps = rollout.env_steps();
  const auto t0 = Clock::now();
  double elapsed = 0;
  do {
    rollout.collect(T, batch);
    elapsed = seconds_since(t0);
  } while (elapsed < seconds);
  return double(rollout.env_steps() - start_steps) / elapsed;
}

// The envs alone: the farm::VecEnv that farm.make_vec steps, its envs split in `threads` contiguous
// ranges that are stepped at once and joined every step (the calling thread steps the first range,
// as farm.make_vec's pool does), with actions drawn before timing as bench_python_vec.py draws them
// (N(0, 0.5) clipped to [-1, 1], or uniform action indices for a discrete task), the steps cycling
// through 16 batches. Env steps/s, resets on episode ends included.
double env_only_steps_per_second(std::shared_ptr<const farm::robots::Task> task, int envs, int threads,
                                 double seconds) {
  farm::VecEnv env(std::move(task), envs, 1);
  env.reset_all();
  const int n = env.num_envs(), discrete = env.spec().num_actions;
  const int k_threads = std::clamp(threads, 1, n);
  std::mt19937_64 rng(1);
  std::normal_distribution<float> noise(0.f, 0.5f);
  std::vector<std::vector<float>> batches(16, std::vector<float>(size_t(n) * env.act_dim()));
  for (auto& b : batches)
    for (auto& a : b)
      a = discrete > 0 ? float(std::uniform_int_distribution<int>(0, discrete - 1)(rng))
                       : std::clamp(noise(rng), -1.f, 1.f);
  std::vector<float> rewards(n);
  std::vector<uint8_t> terminated(n), truncated(n);
  std::vector<farm::EpisodeEnds> ends(k_threads);
  const float* actions = nullptr;  // written before `generation` moves on, read after
  auto step_range = [&](int k) {
    ends[k].clear();
    env.step_range(int(int64_t(n) * k / k_threads), int(int64_t(n) * (k + 1) / k_threads), actions, rewards.data(),
                   terminated.data(), truncated.data(), ends[k]);
  };
  std::atomic<uint64_t> generation{0};
  std::atomic<int> pending{0};
  std::atomic<bool> stop{false};
  std::vector<std::thread> pool;
  for (int k = 1; k < k_threads; ++k) {
    pool.emplace_back([&, k] {
      uint64_t seen = 0;
      for (;;) {
        while (generation.load() == seen && !stop.load()) std::this_thread::yield();
        if (stop.load()) return;
        seen = generation.load();
        step_range(k);
        pending.fetch_sub(1);
      }
    });
  }
  auto step_all = [&](const std::vector<float>& a) {
    actions = a.data();
    pending.store(k_threads - 1);
    generation.fetch_add(1);
    step_range(0);
    while (pending.load() != 0) std::this_thread::yield();
  };
  for (int k = 0; k < 20; ++k) step_all(batches[k % batches.size()]);  // warm-up
  uint64_t steps = 0;
  const auto t0 = Clock::now();
  double elapsed = 0;
  do {
    for (const auto& a : batches) step_all(a);
    steps += uint64_t(batches.size()) * n;
    elapsed = seconds_since(t0);
  } while (elapsed < seconds);
  stop.store(true);
  for (auto& t : pool) t.join();
  return double(steps) / elapsed;
}

double policy_rows_per_second(const farm::PolicyParams& params, int rows, double seconds) {
  farm::Policy policy(params);
  std::vector<float> obs(size_t(rows) * policy.obs_dim(), 0.5f), act(size_t(rows) * policy.act_dim()), lp(rows);
  std::vector<std::mt19937_64> rngs(rows);
  uint64_t done = 0;
  const auto t0 = Clock::now();
  double elapsed = 0;
  do {
    for (int i = 0; i < 1000; ++i) {
      policy.act_per_row(obs.data(), rows, rngs.data(), false, act.data(), lp.data());
    }
    done += uint64_t(1000) * rows;
    elapsed = seconds_since(t0);
  } while (elapsed < seconds);
  return double(done) / elapsed;
}

// The actor the learner would publish for the task: with a PPO or SAC config, its hidden sizes,
// activation and head; otherwise a 64-64 relu net with SAC's [mean | log_std] or DQN's Q values.
// Weights are random: inference costs the same whatever they are.
farm::PolicyParams bench_policy(const farm::config::ExperimentConfig* cfg, const farm::robots::TaskSpec& spec) {
  farm::PolicyParams policy;
  std::vector<int> hidden = {64, 64};
  farm::Activation activation = farm::Activation::kRelu;
  auto from_config = [&](const auto& section, std::vector<int> fallback) {
    hidden.assign(section.hidden().begin(), section.hidden().end());
    if (hidden.empty()) hidden = std::move(fallback);
    activation = farm::activation_from_name(section.activation());
  };
  const int discrete = spec.num_actions;
  int out = discrete > 0 ? discrete : 2 * spec.act_dim;
  if (discrete > 0) {
    policy.head = farm::PolicyHead::kDiscreteQ;
    policy.epsilon = 0.05f;
  } else if (cfg && cfg->algorithm() == "ppo") {
    from_config(cfg->ppo(), {64, 64});
    policy.head = farm::PolicyHead::kGaussian;
    out = spec.act_dim;
    policy.log_std.assign(out, float(cfg->ppo().initial_log_std()));
    policy.log_std_min = float(cfg->ppo().log_std_min());
    policy.log_std_max = float(cfg->ppo().log_std_max());
  } else if (cfg && cfg->algorithm() == "sac") {
    from_config(cfg->sac(), {256, 256});
  }
  policy.layout.sizes = {spec.obs_dim};
  policy.layout.sizes.insert(policy.layout.sizes.end(), hidden.begin(), hidden.end());
  policy.layout.sizes.push_back(out);
  policy.layout.activation = activation;
  policy.params.resize(policy.layout.num_params());
  std::mt19937_64 rng(1);
  std::normal_distribution<float> normal(0.f, 0.2f);
  for (auto& v : policy.params) v = normal(rng);
  return policy;
}

}  // namespace

int main(int argc, char** argv) {
  int envs = 16, threads = int(std::thread::hardware_concurrency());
  double seconds = 2.0;
  std::string task_name = "pendulum", config_path, against_path;
  bool raw_only = false, inference_only = false, env_only = false, envs_given = false, task_given = false;
  const int T = 32;
  farm::cli::App app("bench_worker");
  app.description(
      "Worker throughput against the physics alone: how much of raw mj_step speed survives policy "
      "inference, batching and threading.");
  app.add_option("--task", task_name, "The task to run")
      ->capture_default_str()
      ->each([&task_given](const std::string&) { task_given = true; });
  app.add_option("--config", config_path, "An experiment config whose task and worker settings to run");
  app.add_option("--against", against_path, "A second config whose worker runs beside --config's");
  app.add_option("--envs", envs, "Environments (default with --config: its worker.envs_per_worker)")
      ->check(CLI::Range(1, 1 << 20))
      ->capture_default_str()
      ->each([&envs_given](const std::string&) { envs_given = true; });
  bench::add_threads(app, threads, "Threads that step the environments");
  bench::add_seconds(app, seconds);
  app.add_flag("--raw-only", raw_only, "Measure only the raw physics");
  app.add_flag("--inference-only", inference_only, "Measure only the policy inference");
  app.add_flag("--env-only", env_only, "Measure only the envs, stepped as farm.make_vec steps them, without a policy");
  if (const int rc = farm::cli::parse(app, argc, argv); rc >= 0) return rc;
  if (task_given && !config_path.empty()) {
    std::fprintf(stderr, "--task and --config both name the task: give one\n");
    return 2;
  }
  if (!against_path.empty() && (config_path.empty() || raw_only || inference_only || env_only)) {
    std::fprintf(stderr,
                 "--against sets one config's worker beside --config's: give --config, not --raw-only, "
                 "--inference-only or --env-only\n");
    return 2;
  }
  if (int(raw_only) + int(inference_only) + int(env_only) > 1) {
    std::fprintf(stderr, "--raw-only, --inference-only and --env-only exclude each other: give one\n");
    return 2;
  }

  farm::config::TaskConfig task_cfg;
  task_cfg.set_name(task_name);
  std::shared_ptr<const farm::robots::Task> task;
  farm::config::ExperimentConfig cfg;
  try {
    if (!config_path.empty()) {
      cfg = farm::robots::load_config_file(config_path);
      farm::clear_output_paths(&cfg);  // as a worker does: the task is built, nothing written
      task_cfg = cfg.task();
      if (!envs_given) envs = cfg.worker().envs_per_worker();
    }
    task = farm::robots::make_task(task_cfg);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "bench_worker: %s\n", e.what());
    return 2;
  }
  // Exploration noise of the visited states: the PPO config's initial standard deviation, else
  // half the action range.
  const double action_std =
      !config_path.empty() && cfg.algorithm() == "ppo" ? std::exp(cfg.ppo().initial_log_std()) : 0.5;
  if (env_only) {
    // The task as farm.make_vec makes it: a task name gets its config section's defaults (noise,
    // pushes, randomized dynamics), as a config file would, where --task alone sets only the name.
    std::shared_ptr<const farm::robots::Task> made = task;
    if (config_path.empty()) {
      try {
        made = farm::robots::make_task(
            farm::robots::parse_config_text("experiment_id: \"python\" task { name: \"" + task_name + "\" }", task_name)
                .task());
      } catch (const std::exception& e) {
        std::fprintf(stderr, "bench_worker: %s\n", e.what());
        return 2;
      }
    }
    std::printf("task %s as farm.make_vec makes it, %d envs, %.1f s per measurement, no policy\n",
                made->spec().name.c_str(), envs, seconds);
    const int k = std::min(threads, envs);
    std::printf("env-only VecEnv %d thread(s): %.0f env steps/s\n", k,
                env_only_steps_per_second(made, envs, k, seconds));
    return 0;
  }
  if (raw_only) {
    // Only the limit: K loops at once, each one's env steps/s (what one single-threaded worker
    // among K on this host can reach at most) and their mean; the limit is mj_step over the states
    // the task visits, the resting-state loop is printed beside it.
    const RawStart start = raw_start(*task);
    const double per = start.physics_per_env_step;
    const int per_int = std::max(1, int(per + 0.5));
    const VisitedStates visited = visited_states(*task, envs, per, action_std);
    const std::vector<double> loops =
        on_threads(threads, [&] { return visited_steps_per_second(*task, visited, envs, per_int, seconds) / per_int; });
    const std::vector<double> resting = raw_parallel_loops(task->model(), start.data, threads, seconds);
    double sum = 0, sum_resting = 0;
    std::printf(
        "task %s, %.2f physics steps per env step, %d mj_step loops at once, %.1f s; %zu visited states "
        "(%d episodes x %d env steps, action std %.3f)\n",
        task->spec().name.c_str(), per, threads, seconds, visited.size(), visited.episodes, visited.steps_per_episode,
        action_std);
    for (int k = 0; k < threads; ++k) {
      std::printf("raw loop %d: %.0f env steps/s over visited states, %.0f from one resting state\n", k, loops[k],
                  resting[k] / per);
      sum += loops[k];
      sum_resting += resting[k] / per;
    }
    std::printf("resting-state raw per loop (%d at once): %.0f env steps/s\n", threads, sum_resting / threads);
    std::printf("raw per loop (%d at once): %.0f env steps/s\n", threads, sum / threads);
    return 0;
  }
  const farm::PolicyParams policy = bench_policy(config_path.empty() ? nullptr : &cfg, task->spec());
  // The kernel path the policy runs (FARM_MLP_ISA or the CPU; see common/mlp.h).
  const char* isa = nullptr;
  try {
    isa = farm::mlp_isa_name(farm::EigenMlp(policy.layout, policy.params).isa());
  } catch (const std::exception& e) {
    std::fprintf(stderr, "bench_worker: %s\n", e.what());
    return 2;
  }
  if (inference_only) {
    std::printf("task %s, policy %s (%s kernel), %.1f s per measurement\n", task->spec().name.c_str(),
                policy.layout.describe().c_str(), isa, seconds);
    std::vector<int> row_counts = {1, 8, 64};
    if (envs != 1 && envs != 8 && envs != 64) row_counts.push_back(envs);
    for (int rows : row_counts) {
      std::printf("policy inference (%d rows per call): %.0f rows/s\n", rows,
                  policy_rows_per_second(policy, rows, seconds));
    }
    return 0;
  }

  if (!against_path.empty()) {
    std::shared_ptr<const farm::robots::Task> other;
    farm::config::ExperimentConfig other_cfg;
    try {
      other_cfg = farm::robots::load_config_file(against_path);
      farm::clear_output_paths(&other_cfg);
      other = farm::robots::make_task(other_cfg.task());
    } catch (const std::exception& e) {
      std::fprintf(stderr, "bench_worker: %s\n", e.what());
      return 2;
    }
    const farm::PolicyParams other_policy = bench_policy(&other_cfg, other->spec());
    std::printf("%s (task %s) against %s (task %s): policy %s, %d envs, T=%d, %.1f s per measurement\n",
                config_path.c_str(), task->spec().name.c_str(), against_path.c_str(), other->spec().name.c_str(),
                policy.layout.describe().c_str(), envs, T, seconds);
    for (const int k : {1, std::min(threads, envs)}) {
      double mine = 0, theirs = 0;
      for (int rep = 0; rep < 2; ++rep) {
        mine += worker_steps_per_second(task, policy, envs, k, T, seconds) / 2;
        theirs += worker_steps_per_second(other, other_policy, envs, k, T, seconds) / 2;
      }
      std::printf("worker %d thread(s): %.0f env steps/s (%s), %.0f env steps/s (%s): ratio %.3f\n", k, mine,
                  task->spec().name.c_str(), theirs, other->spec().name.c_str(), mine / theirs);
    }
    return 0;
  }
  std::printf("task %s, policy %s (%s kernel), %d envs, T=%d, %.1f s per measurement\n", task->spec().name.c_str(),
              policy.layout.describe().c_str(), isa, envs, T, seconds);
  const RawStart start = raw_start(*task);
  const double per = start.physics_per_env_step;
  const double raw = raw_steps_per_second(task->model(), start.data, seconds) / per;
  std::printf("raw mj_step from one resting state: %.0f steps/s, %.2f per env step: %.0f env steps/s\n", raw * per, per,
              raw);
  const int per_int = std::max(1, int(per + 0.5));
  const VisitedStates visited = visited_states(*task, envs, per, action_std);
  const double vis1 = visited_steps_per_second(*task, visited, 1, per_int, seconds) / per_int;
  std::printf("raw mj_step over %zu visited states (action std %.3f) in one mjData: %.0f env steps/s\n", visited.size(),
              action_std, vis1);
  const double vis = visited_steps_per_second(*task, visited, envs, per_int, seconds) / per_int;
  std::printf(
      "raw mj_step over the visited states in the %d envs' own mjData: limit %.0f env steps/s (%.3f of the "
      "resting state's)\n",
      envs, vis, vis / raw);
  const double infer = policy_rows_per_second(policy, envs, seconds);
  std::printf("policy inference (%d rows per call): %.0f rows/s\n", envs, infer);

  const double w1 = worker_steps_per_second(task, policy, envs, 1, T, seconds);
  std::printf("worker 1 thread: %.0f env steps/s\n", w1);
  std::printf("ratio worker/limit (1 thread): %.3f (against the resting state: %.3f)\n", w1 / vis, w1 / raw);

  const int k = std::min(threads, envs);
  const double wk = worker_steps_per_second(task, policy, envs, k, T, seconds);
  std::printf("worker %d threads: %.0f env steps/s\n", k, wk);
  std::printf("resting-state raw x %d threads: %.0f env steps/s\n", k, raw * k);
  std::printf("ratio worker/(resting-state raw x threads) (%d threads): %.3f\n", k, wk / (raw * k));
  std::printf("speedup %d threads over 1: %.2f\n", k, wk / w1);
  const double raw_k = raw_parallel_steps_per_second(task->model(), start.data, k, seconds) / per;
  std::printf("resting-state raw mj_step on %d threads at once (measured): %.0f env steps/s\n", k, raw_k);
  std::printf("ratio worker/(measured parallel resting-state raw) (%d threads): %.3f\n", k, wk / raw_k);
  return 0;
}
