// Proximal Policy Optimization (Schulman et al. 2017) as MushroomRL's PPO: a Gaussian policy with a
// state-independent learned log-std, a value network, GAE, the clipped surrogate, a value loss and
// an entropy bonus, several epochs over shuffled mini-batches; and, for the variant the MushroomRL paper
// trains its quadrupeds with (§4, appendix), gradient-norm clipping and a learning rate that
// follows the KL between the old and the new policy. Observations are normalized with running
// statistics the learner keeps and ships with the weights.
#pragma once

#include <torch/torch.h>

#include <cstdint>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "farm_config.pb.h"
#include "mlp.h"
#include "obs_normalizer.h"

namespace farm {

// The KL-adaptive rate of the MushroomRL paper's modified PPO: divided by lr_factor when kl > kl_band *
// desired_kl, multiplied by lr_factor when kl < desired_kl / kl_band, kept in [lr_min, lr_max].
double adapt_learning_rate(double lr, double kl, const config::PpoConfig& cfg);

// One fit's data, flattened: row i is one step.
struct PpoSamples {
  int64_t n = 0;
  std::vector<float> obs;                 // [n x obs_dim], raw (the fit normalizes)
  std::vector<float> actions;             // [n x act_dim], as the env ran them (in [-1, 1])
  std::vector<float> behaviour_log_prob;  // [n], sent by the worker
  // [n]: 1 where the step was made by the version being fitted: its ratio denominator is
  // recomputed (the same policy); 0 for older data (carried over, or lag >= 1): the ratio is
  // taken against the behaviour log-probability the worker sent.
  std::vector<uint8_t> current;
  std::vector<float> advantages, returns;  // [n]
};

struct PpoStats {
  double kl = 0;             // mean KL(old || new) over the fit's data, after the fit
  double learning_rate = 0;  // after the fit (the KL-adaptive rate moves it)
  double clip_fraction = 0;  // share of samples whose ratio left [1 - eps, 1 + eps], last epoch
  double value_loss = 0;     // mean over the last epoch's mini-batches
  double policy_loss = 0;
  double entropy = 0;    // of the Gaussian, per step, after the fit
  double grad_norm = 0;  // mean before clipping, last epoch
  int64_t samples = 0;
  int64_t minibatches = 0;
};

class Ppo {
 public:
  // Seeds torch's global generator with `seed`.
  Ppo(const config::PpoConfig& cfg, int obs_dim, int act_dim, uint64_t seed);
  ~Ppo();

  // V(obs) for raw observations [n x obs_dim] -> [n], with the current normalizer.
  std::vector<float> values(const float* obs, int64_t n) const;
  // The clipped-Gaussian log-probability of actions at obs under the current policy -> [n].
  std::vector<float> log_probs(const float* obs, const float* actions, int64_t n) const;
  // Epochs of clipped-surrogate updates over shuffled mini-batches of `s`.
  PpoStats fit(const PpoSamples& s);

  // The actor as workers run it: Gaussian head, the current normalizer and log-std.
  PolicyParams export_policy(uint64_t version) const;
  ObsNormalizer& normalizer();
  const ObsNormalizer& normalizer() const;
  double learning_rate() const;
  torch::Device device() const;  // where the networks fit
  int64_t fits() const;
  int64_t updates() const;  // mini-batch gradient steps

  // DIR/ppo.pt (networks, log-std, optimizer, normalizer, rate); written to a temporary file and
  // renamed. load() throws std::runtime_error naming the file on a mismatch.
  void save(const std::string& dir) const;
  void load(const std::string& dir);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace farm
