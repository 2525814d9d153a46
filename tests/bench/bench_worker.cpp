// Worker throughput against the physics alone: how much of raw mj_step speed survives policy
// inference, batching and threading. Usage: bench_worker [--envs N] [--threads K] [--seconds S]
#include <mujoco/mujoco.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "mlp.h"
#include "rollout.h"
#include "task.h"

namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

double raw_steps_per_second(const mjModel* m, double seconds) {
  mjData* d = mj_makeData(m);
  // Hanging, with a torque below m g l / 2: it swings about a tilted rest point forever. A
  // start near upright would go over the top and spin up without bound (the torque keeps
  // adding energy), until MuJoCo resets the diverged state.
  d->qpos[0] = 3.14159265358979;
  d->ctrl[0] = 0.5;
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
// cores, turbo limits), so the worker's scaling can be told apart from the machine's.
double raw_parallel_steps_per_second(const mjModel* m, int threads, double seconds) {
  std::vector<double> rates(threads);
  std::vector<std::thread> pool;
  for (int k = 0; k < threads; ++k) {
    pool.emplace_back([&, k] { rates[k] = raw_steps_per_second(m, seconds); });
  }
  for (auto& t : pool) t.join();
  double total = 0;
  for (double r : rates) total += r;
  return total;
}

double worker_steps_per_second(std::shared_ptr<const farm::robots::Task> task,
                               const farm::PolicyParams& policy, int envs, int threads, int T,
                               double seconds) {
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

double policy_rows_per_second(const farm::PolicyParams& params, int rows, double seconds) {
  farm::Policy policy(params);
  std::vector<float> obs(size_t(rows) * policy.obs_dim(), 0.5f), act(rows), lp(rows);
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

}  // namespace

int main(int argc, char** argv) {
  int envs = 16, threads = int(std::thread::hardware_concurrency());
  double seconds = 2.0;
  const int T = 32;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (i + 1 < argc && a == "--envs") {
      envs = std::atoi(argv[++i]);
    } else if (i + 1 < argc && a == "--threads") {
      threads = std::atoi(argv[++i]);
    } else if (i + 1 < argc && a == "--seconds") {
      seconds = std::atof(argv[++i]);
    } else {
      std::fprintf(stderr, "usage: %s [--envs N] [--threads K] [--seconds S]\n", argv[0]);
      return 2;
    }
  }
  if (envs < 1 || threads < 1 || !(seconds > 0)) {
    std::fprintf(stderr, "--envs and --threads must be >= 1, --seconds > 0\n");
    return 2;
  }

  std::shared_ptr<const farm::robots::Task> task = farm::robots::make_task({});
  farm::PolicyParams policy;
  policy.layout = {{task->spec().obs_dim, 64, 64, 2 * task->spec().act_dim},
                   farm::Activation::kRelu};
  policy.params.resize(policy.layout.num_params());
  std::mt19937_64 rng(1);
  std::normal_distribution<float> normal(0.f, 0.2f);
  for (auto& v : policy.params) v = normal(rng);

  std::printf("task %s, policy %s, %d envs, T=%d, %.1f s per measurement\n",
              task->spec().name.c_str(), policy.layout.describe().c_str(), envs, T, seconds);
  const double raw = raw_steps_per_second(task->model(), seconds);
  std::printf("raw mj_step: %.0f steps/s\n", raw);
  const double infer = policy_rows_per_second(policy, envs, seconds);
  std::printf("policy inference (%d rows per call): %.0f rows/s\n", envs, infer);

  const double w1 = worker_steps_per_second(task, policy, envs, 1, T, seconds);
  std::printf("worker 1 thread: %.0f env steps/s\n", w1);
  std::printf("ratio worker/raw (1 thread): %.3f\n", w1 / raw);

  const int k = std::min(threads, envs);
  const double wk = worker_steps_per_second(task, policy, envs, k, T, seconds);
  std::printf("worker %d threads: %.0f env steps/s\n", k, wk);
  std::printf("raw x %d threads: %.0f steps/s\n", k, raw * k);
  std::printf("ratio worker/(raw x threads) (%d threads): %.3f\n", k, wk / (raw * k));
  std::printf("speedup %d threads over 1: %.2f\n", k, wk / w1);
  const double raw_k = raw_parallel_steps_per_second(task->model(), k, seconds);
  std::printf("raw mj_step on %d threads at once (measured): %.0f steps/s\n", k, raw_k);
  std::printf("ratio worker/(measured parallel raw) (%d threads): %.3f\n", k, wk / raw_k);
  return 0;
}
