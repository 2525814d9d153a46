// T steps x N environments of experience as a worker collects it, laid out as on the wire
// (index [t][n][...]), so publishing is a copy into the DDS sample and nothing else.
#pragma once

#include <cstdint>
#include <vector>

namespace farm {

struct EpisodeRecord {
  int32_t env = 0;
  float episode_return = 0.f;
  int32_t length = 0;
  bool terminated = false;
  std::vector<float> metrics;
};

struct RolloutBatch {
  int T = 0, N = 0, obs_dim = 0, act_dim = 0;
  uint64_t policy_version = 0;
  std::vector<float> obs;               // [T][N][obs_dim]: observation the action was taken in
  std::vector<float> actions;           // [T][N][act_dim]
  std::vector<float> rewards;           // [T][N]
  std::vector<uint8_t> terminated;      // [T][N]
  std::vector<uint8_t> truncated;       // [T][N]
  std::vector<float> log_probs;         // [T][N]: behaviour log-probability of the action
  std::vector<float> next_obs;          // [N][obs_dim]: observation after the last step (to bootstrap)
  std::vector<uint32_t> final_index;    // t * N + n for every step where an episode ended
  std::vector<float> final_obs;         // [final_index.size()][obs_dim]: true last observation
  std::vector<EpisodeRecord> episodes;  // episodes that finished in this batch
  void resize(int T, int N, int obs_dim, int act_dim);
  // Appends a record to `episodes`, reusing one of an earlier batch (and its metrics storage),
  // so that a refilled batch allocates nothing once it has held as many episodes before.
  EpisodeRecord& add_episode();

 private:
  std::vector<EpisodeRecord> spare_episodes_;
};

}  // namespace farm
