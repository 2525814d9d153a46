// The quadruped benchmarks' task rate: env steps/s of a task with uniformly random actions in
// [-0.5, 0.5], episodes reset as they end (bench_quadruped, and bench_a1_step on edited models).
#pragma once

#include <chrono>
#include <cstdint>
#include <random>
#include <vector>

#include "quadruped/quadruped_task.h"
#include "task.h"

namespace farm::bench {

// Steps the task on state `s` (made by the caller, e.g. moved onto another model) for `seconds`;
// *episodes, if given, counts the episodes that ended.
inline double random_action_rate(const robots::quadruped::QuadrupedTask& task, robots::TaskState& s, double seconds,
                                 uint64_t* episodes = nullptr) {
  using Clock = std::chrono::steady_clock;
  std::vector<float> obs(task.spec().obs_dim), a(task.spec().act_dim);
  std::mt19937_64 rng(1);
  std::uniform_real_distribution<float> u(-0.5f, 0.5f);
  uint64_t seed = 1, steps = 0, ended = 0;
  task.reset(s, seed++, obs.data());
  const auto t0 = Clock::now();
  double elapsed = 0;
  do {
    for (int i = 0; i < 100; ++i) {
      for (auto& x : a) x = u(rng);
      const auto r = task.step(s, a.data(), obs.data());
      if (r.terminated || r.truncated) {
        task.reset(s, seed++, obs.data());
        ++ended;
      }
    }
    steps += 100;
    elapsed = std::chrono::duration<double>(Clock::now() - t0).count();
  } while (elapsed < seconds);
  if (episodes) *episodes = ended;
  return double(steps) / elapsed;
}

}  // namespace farm::bench
