// Experience collection for one worker: a VecEnv stepped by a persistent thread pool. Thread k
// owns a contiguous chunk of envs and a copy of the policy, and runs all T steps of a batch for
// its chunk (batched inference over its rows, then stepping), writing straight into the
// RolloutBatch; threads meet only at the start and the end of collect().
// Action noise comes from one generator per env, so a batch depends on the seed only, not on
// the number of threads.
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <exception>
#include <functional>
#include <memory>
#include <mutex>
#include <random>
#include <thread>
#include <vector>

#include "mlp.h"
#include "rollout_batch.h"
#include "task.h"
#include "vec_env.h"

namespace farm {

class Rollout {
 public:
  // Resets every env. num_threads is capped at num_envs; the calling thread runs chunk 0.
  // Throws std::invalid_argument if num_envs or num_threads is < 1.
  Rollout(std::shared_ptr<const robots::Task> task, int num_envs, int num_threads, uint64_t seed);
  ~Rollout();
  Rollout(const Rollout&) = delete;
  Rollout& operator=(const Rollout&) = delete;

  // Throws std::invalid_argument if the policy is inconsistent or does not fit the task's
  // observation/action sizes. Call between collect()s, not during one.
  void set_policy(const PolicyParams& p);
  uint64_t policy_version() const { return version_; }

  // Collects T steps of every env into `out` (resized to T x N). Episodes continue across
  // calls. Throws std::logic_error before set_policy(); rethrows a task's exception.
  void collect(int T, RolloutBatch& out);

  uint64_t env_steps() const { return env_steps_; }  // over all collect() calls

  // worker.exploration_scale_min/max: each env draws a factor on its policy noise uniformly in
  // [lo, hi] now and at the start of each of its episodes, from its own noise generator. 1 and
  // 1: none (the policy's own noise). Call between collect()s.
  void set_exploration_scales(double lo, double hi);
  // The env's current factor (1 where none is set).
  float exploration_scale(int env) const { return scale_.empty() ? 1.f : scale_[size_t(env)]; }
  // Where collect() time went, over all calls: thread-seconds in policy inference and in
  // stepping the simulation, summed over the pool's threads, and wall seconds inside collect().
  struct Timing {
    double infer_s = 0, simulate_s = 0, collect_s = 0;
  };
  Timing timing() const;
  int num_envs() const { return env_.num_envs(); }
  int num_threads() const { return int(chunks_.size()); }
  const robots::TaskSpec& spec() const { return env_.spec(); }
  const VecEnv& env() const { return env_; }

 private:
  struct Chunk {
    int begin = 0, end = 0;
    Policy policy;
    EpisodeEnds ends;
    std::vector<uint32_t> end_index;  // t * N + n of each entry of `ends`
    double infer_s = 0, simulate_s = 0;
  };
  void run_chunk(Chunk& c, int T, RolloutBatch& out);
  void thread_main(int k);
  void merge_ends(RolloutBatch& out);

  VecEnv env_;
  std::vector<std::mt19937_64> noise_rng_;  // per env
  std::vector<float> scale_;                // per env: set_exploration_scales; empty: none
  float scale_lo_ = 1.f, scale_hi_ = 1.f;
  float draw_scale(int env);
  std::vector<Chunk> chunks_;
  uint64_t version_ = 0;
  bool has_policy_ = false;
  uint64_t env_steps_ = 0;
  double collect_s_ = 0;

  // Job hand-off to the pool: one generation per collect().
  std::vector<std::thread> threads_;  // thread k - 1 runs chunk k
  std::mutex mu_;
  std::condition_variable start_cv_, done_cv_;
  uint64_t generation_ = 0;
  int pending_ = 0;
  bool stop_ = false;
  int job_T_ = 0;
  RolloutBatch* job_out_ = nullptr;
  std::exception_ptr error_;
  std::vector<std::pair<uint32_t, std::pair<int, int>>> merge_order_;  // (index, (chunk, i))
};

// Runs `episodes` complete episodes, one per env, side by side, with the deterministic policy
// (tanh(mean)), and returns their records ordered by env. Throws std::invalid_argument if the
// policy does not fit the task or the task has no time limit. cancel, if given and set, ends it
// between two steps with an empty result.
// first_episode: the index of the first of them in a larger evaluation of the same seed. Episode k
// is episode first_episode + k of that evaluation: reset as that episode is (VecEnv's env
// first_episode + k), so an evaluation split into parts runs the episodes it would run whole,
// however many parts answer it; where the task has evaluation conditions
// (robots::Task::eval_conditions), it starts in condition (first_episode + k) mod their number.
// on_step, where given, sees every step's observations and the actions computed for them, before
// the envs step ([episodes x obs_dim] and [episodes x act_dim] floats; an action index as a float).
using EvaluationStep = std::function<void(const float* obs, const float* actions, int rows)>;
std::vector<EpisodeRecord> evaluate_policy(std::shared_ptr<const robots::Task> task, const PolicyParams& params,
                                           int episodes, uint64_t seed, const std::atomic<bool>* cancel = nullptr,
                                           uint32_t first_episode = 0, const EvaluationStep& on_step = nullptr);

}  // namespace farm
