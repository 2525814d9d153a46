#include "rollout_batch.h"

#include <cstddef>

namespace farm {

// Sizes every per-step array for T x N; the per-episode lists are emptied but keep their
// storage, so refilling a batch of the same shape does not allocate.
void RolloutBatch::resize(int T_, int N_, int obs_dim_, int act_dim_) {
  T = T_;
  N = N_;
  obs_dim = obs_dim_;
  act_dim = act_dim_;
  const size_t steps = size_t(T_) * size_t(N_);
  obs.resize(steps * obs_dim_);
  actions.resize(steps * act_dim_);
  rewards.resize(steps);
  terminated.resize(steps);
  truncated.resize(steps);
  log_probs.resize(steps);
  next_obs.resize(size_t(N_) * obs_dim_);
  final_index.clear();
  final_obs.clear();
  for (auto& e : episodes) spare_episodes_.push_back(std::move(e));
  episodes.clear();
}

EpisodeRecord& RolloutBatch::add_episode() {
  if (spare_episodes_.empty()) return episodes.emplace_back();
  episodes.push_back(std::move(spare_episodes_.back()));
  spare_episodes_.pop_back();
  return episodes.back();
}

}  // namespace farm
