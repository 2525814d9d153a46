// N environments of one task stepped as a vector: the task (model, constants) is shared, each
// env has its own TaskState, and observations live in one contiguous [N x obs_dim] buffer so
// the policy reads them as a batch. Disjoint env ranges may be stepped from different threads.
// Tasks keep TaskState::step and episode_return themselves (reset zeroes them, step advances
// them); VecEnv reads them into each EpisodeRecord.
#pragma once

#include <cstdint>
#include <memory>
#include <vector>

#include "rollout_batch.h"
#include "task.h"

namespace farm {

// splitmix64: advances `state` and returns the next output. Used to derive independent,
// well-mixed seeds from one experiment seed (neighbouring inputs give unrelated outputs).
inline uint64_t splitmix64(uint64_t& state) {
  uint64_t z = (state += 0x9E3779B97F4A7C15ull);
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

// The seed of stream `stream` (an env index, a purpose tag) under experiment seed `seed`.
inline uint64_t mix_seed(uint64_t seed, uint64_t stream) {
  uint64_t s = seed;
  uint64_t a = splitmix64(s);
  s = a ^ (stream * 0xD1B54A32D192ED03ull);
  return splitmix64(s);
}

// Episodes that ended during step_range() calls, in the order they ended. Entries keep their
// storage across clear(), so recording an episode end does not allocate once warmed up.
class EpisodeEnds {
 public:
  void clear() { size_ = 0; }
  int size() const { return size_; }
  int env(int i) const { return records_[i].env; }
  const EpisodeRecord& record(int i) const { return records_[i]; }
  const float* final_obs(int i) const { return final_obs_.data() + size_t(i) * obs_dim_; }
  // Appends an entry; fill the returned record and write obs_dim floats to *final_obs.
  EpisodeRecord& add(int obs_dim, float** final_obs);

 private:
  int size_ = 0;
  int obs_dim_ = 0;
  std::vector<EpisodeRecord> records_;
  std::vector<float> final_obs_;
};

class VecEnv {
 public:
  // Env i's reset seeds come from its own generator seeded with mix_seed(seed, first_index + i):
  // envs first_index.. of a larger set made from the same seed (evaluate_policy's parts). Envs are
  // not reset here: call reset_all() before the first step.
  VecEnv(std::shared_ptr<const robots::Task> task, int num_envs, uint64_t seed, uint64_t first_index = 0);

  const robots::Task& task() const { return *task_; }
  const robots::TaskSpec& spec() const { return task_->spec(); }
  int num_envs() const { return int(states_.size()); }
  int obs_dim() const { return obs_dim_; }
  int act_dim() const { return act_dim_; }

  // Starts a new episode in every env (each with the next seed of its generator).
  void reset_all();
  // Restarts every env's seed generator as the constructor does for `seed` (no env is reset).
  void reseed(uint64_t seed);
  // Restarts env `env`'s seed generator alone, as reseed(seed) restarts env `stream`'s of a VecEnv
  // made with first_index 0. With stream 0, an env reseeded with `seed` repeats the episodes of a
  // one-env VecEnv of seed `seed`, whatever its index (Gymnasium's reset(seed=[...]), each env its
  // own seed); with stream `env`, it is reseeded as reseed(seed) would (a partial reset with one seed).
  void reseed_env(int env, uint64_t seed, uint64_t stream = 0);
  void reset(int env);
  // Starts a new episode in env `env` in the task's evaluation condition `condition`.
  void reset_in_condition(int env, int condition);

  const float* obs() const { return obs_.data(); }  // [N x obs_dim]
  const float* obs(int env) const { return obs_.data() + size_t(env) * obs_dim_; }
  const robots::TaskState& state(int env) const { return *states_[env]; }

  // Steps envs [begin, end). Arrays are indexed by env over all N envs (actions [N x act_dim],
  // rewards/terminated/truncated [N]); only rows [begin, end) are read or written. An env whose
  // episode ends has its true last observation and EpisodeRecord appended to `ends`, and is
  // reset at once, so obs(env) is then the first observation of its next episode.
  void step_range(int begin, int end, const float* actions, float* rewards, uint8_t* terminated, uint8_t* truncated,
                  EpisodeEnds& ends);

 private:
  std::shared_ptr<const robots::Task> task_;
  int obs_dim_ = 0, act_dim_ = 0, num_metrics_ = 0;
  std::vector<std::unique_ptr<robots::TaskState>> states_;
  uint64_t first_index_ = 0;
  std::vector<uint64_t> seed_state_;  // per-env splitmix64 state for reset seeds
  std::vector<float> obs_;
};

}  // namespace farm
