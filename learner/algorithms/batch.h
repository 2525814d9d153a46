// Data as the algorithms receive it: the transitions of one batch that ingest accepted, flattened,
// with the finished episodes it reported. No wire types here: the farm side converts.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace farm {

// Transitions flattened for a replay buffer: row i is (obs, action, reward, terminated, next_obs),
// plus its horizon (steps from obs to next_obs) once fold_n_step has run; empty horizon: all 1.
struct Transitions {
  int64_t n = 0;
  std::vector<float> obs, actions, rewards, next_obs, horizon;
  std::vector<uint8_t> terminated;
  void clear() {
    n = 0;
    obs.clear();
    actions.clear();
    rewards.clear();
    next_obs.clear();
    horizon.clear();
    terminated.clear();
  }
};

struct FinishedEpisode {
  std::string worker_id;
  float episode_return = 0.f;
  uint32_t length = 0;
  std::vector<float> metrics;
};

// One accepted batch of T steps of N environments, rows in [t][n] order.
struct Batch {
  std::string worker_id;
  uint64_t policy_version = 0;  // the version that made it
  int num_steps = 0, num_envs = 0;
  const uint8_t* truncated = nullptr;  // T*N
  const float* log_probs = nullptr;    // T*N, of the behaviour policy
  Transitions* rows = nullptr;         // its T*N rows (an end-of-stream batch has none)
  const std::vector<FinishedEpisode>* episodes = nullptr;
};

// Folds the one-step rows just appended for a batch of T steps x N envs (the last T*N rows of
// `rows`, in [t][n] order) into n-step rows, in place: row (t, e) gets r_t + gamma r_{t+1} + ... +
// gamma^(m-1) r_{t+m-1}, the next observation and `terminated` of step t+m-1, and horizon m, where
// m <= n_step stops early at the step that ends env e's episode (terminated or truncated) or at the
// batch's last step. Nothing is dropped: every row stays, the last ones of a batch with shorter
// horizons.
void fold_n_step(int64_t num_steps, int64_t num_envs, const uint8_t* truncated, Transitions& rows, double gamma,
                 int n_step);

}  // namespace farm
