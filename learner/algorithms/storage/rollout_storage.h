// On-policy storage: the steps collected for the next fit, kept as per-env trajectories so that
// GAE runs along each env's steps, and so that a fit can take exactly the steps it needs and
// carry the rest over (a trajectory is split where the fit ends; its tail stays).
#pragma once

#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <string>
#include <vector>

#include "ppo.h"

namespace farm {

class RolloutStorage {
 public:
  RolloutStorage(int obs_dim, int act_dim) : obs_dim_(obs_dim), act_dim_(act_dim) {}

  // One batch, T steps x N envs, arrays [t][n][...] row-major as on the wire; next_obs is the
  // observation after each step ([T x N x obs_dim]; the true final observation where an episode
  // ended). Kept as N trajectories of T steps, made by policy `version`.
  void add(int T, int N, const float* obs, const float* actions, const float* rewards, const uint8_t* terminated,
           const uint8_t* truncated, const float* log_probs, const float* next_obs, uint64_t version);

  int64_t steps() const { return steps_; }
  void clear();

  using ValueFn = std::function<std::vector<float>(const float* obs, int64_t n)>;
  using LogProbFn = std::function<std::vector<float>(const float* obs, const float* actions, int64_t n)>;
  // The asynchronous mode's off-policy correction: V-trace (gae.h) with the current policy's
  // log-probabilities of the stored actions against those the workers sent.
  struct VTrace {
    LogProbFn log_prob;
    double rho_bar = 1.0, c_bar = 1.0;
  };
  // GAE over every stored trajectory with `value` (each trajectory bootstraps on the value of
  // the observation after its last step unless that step terminated), or V-trace where `vtrace`
  // is given, then moves the first `steps` steps (oldest first) into `out`; the rest stays for the
  // next fit. current[] marks the steps made by `current_version`. steps_by_version, if given,
  // gets how many of the taken steps each policy version made.
  void take(int64_t steps, const ValueFn& value, double gamma, double lambda, uint64_t current_version, PpoSamples& out,
            const VTrace* vtrace = nullptr, std::map<uint64_t, int64_t>* steps_by_version = nullptr);

  // Drops the stored steps made by versions older than min_version; returns how many.
  int64_t drop_older_than(uint64_t min_version);
  // Adds `offset` to every stored step's version: a resumed learner publishes the checkpoint's
  // networks under a new number, and the steps they made keep their lag to it.
  void shift_versions(uint64_t offset);

  // The stored steps to a file and back (a checkpoint's part), so that steps accepted and not yet
  // fitted survive a resume. load() replaces what is stored; it throws std::runtime_error naming
  // the file and what is wrong (another obs or action size, a truncated or inconsistent file),
  // and then holds nothing.
  void save(const std::string& file) const;
  void load(const std::string& file);

 private:
  struct Trajectory {
    uint64_t version = 0;
    int64_t len = 0;
    std::vector<float> obs, actions, rewards, log_probs, next_obs;
    std::vector<uint8_t> terminated, truncated;
  };
  int obs_dim_, act_dim_;
  std::deque<Trajectory> trajs_;
  int64_t steps_ = 0;
};

}  // namespace farm
