// SAC with the large-batch recipe of FastTD3, as FastSAC (Seo, Sferrazza, Chen, Shi, Duan, Abbeel
// 2025, "Learning Sim-to-Real Humanoid Locomotion in 15 Minutes", arXiv 2512.01996, and its
// reference implementation, holosoma's fast_sac): two C51 critics with layer normalization and
// SiLU, the soft target (reward minus the discounted temperature times the next action's
// log-probability) projected onto their support, cross-entropy losses, a squashed-Gaussian actor
// that steps once every policy_delay critic updates against the mean of the critics' expected
// values, a temperature learned toward a target entropy, polyak target critics, AdamW,
// observations normalized by running moments. The C51 parts are TD3's (td3.h).
#pragma once

#include <torch/torch.h>

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "farm_config.pb.h"
#include "mlp.h"
#include "replay_buffer.h"

namespace farm {

// One update's numbers. critic_loss sums both critics' cross-entropy (each a mean over the batch);
// alpha is the temperature the critics' target used (before this update's temperature step);
// alpha_loss the temperature's loss; entropy -mean log-probability of the next actions the target
// drew; actor_loss the actor's loss at its latest step (0 before its first); q_mean averages both
// critics' expected values on the batch's (obs, action).
struct FastSacStats {
  double critic_loss = 0, actor_loss = 0, alpha = 0, alpha_loss = 0, entropy = 0, q_mean = 0;
  bool actor_stepped = false;  // this update stepped the actor
};

// The critics' targets [2, B, K] from the target critics' distributions p1, p2 [B, K] at the next
// observation and the actor's sampled next action of log-probability next_log_prob [B]: the
// distribution of r - discount * alpha * next_log_prob + discount * z, projected back onto the
// support (c51_projection), for each critic its own target critic's, or with clipped double Q the
// one of the smaller expected value for both (td3_critic_target). discount [B] is gamma^h * (1 -
// terminated).
torch::Tensor fastsac_critic_target(const torch::Tensor& next_probs1, const torch::Tensor& next_probs2,
                                    const torch::Tensor& rewards, const torch::Tensor& discount,
                                    const torch::Tensor& next_log_prob, const torch::Tensor& alpha, double v_min,
                                    double v_max, bool clipped_double_q);

// FastSAC's temperature loss, -mean(exp(log_alpha) * (log_prob + target_entropy).detach()): its
// gradient raises the temperature while the entropy (-log_prob) is below the target and lowers it
// above. (SAC's, sac_temperature_loss, multiplies log_alpha instead of the temperature.)
torch::Tensor fastsac_temperature_loss(const torch::Tensor& log_alpha, const torch::Tensor& log_prob,
                                       double target_entropy);

// The actor's loss, mean(alpha * log_prob - Q), Q the critics' expected values q [2, B] at the
// actor's sampled actions: their mean, or with clipped double Q their minimum. alpha is a
// constant here (no gradient reaches the temperature).
torch::Tensor fastsac_actor_loss(const torch::Tensor& q, const torch::Tensor& log_prob, const torch::Tensor& alpha,
                                 bool clipped_double_q);

class FastSac {
 public:
  // Seeds torch's global generator with `seed` (initial weights and the actor's samples).
  FastSac(const config::FastSacConfig& cfg, int obs_dim, int act_dim, uint64_t seed);
  ~FastSac();
  FastSac(FastSac&&) noexcept;
  FastSac& operator=(FastSac&&) noexcept;

  // One critic step, the temperature's (where fastsac.autotune), the actor's where its turn comes
  // (updates u with u % policy_delay == 1, or every update with a delay of 1), then the polyak
  // step of the target critics. Rows with a horizon h (fastsac.n_step) bootstrap with gamma^h.
  // Observations are raw: the update normalizes them with the running moments (observe()).
  FastSacStats update(const SampledBatch& batch);
  // Adds rows x obs_dim observations to the running moments (where fastsac.normalize_observations).
  void observe(const float* obs, int64_t rows);

  // The actor as the workers run it: layout {obs, hidden..., 2*act} in fastsac.activation,
  // squashed-Gaussian head with fastsac's log-std bounds, the observation normalizer where
  // fastsac.normalize_observations.
  PolicyParams export_policy(uint64_t version) const;

  int64_t updates() const;
  bool on_gpu() const;
  torch::Device device() const;
  int obs_dim() const;
  int act_dim() const;
  const std::vector<int>& hidden() const;
  const std::vector<int>& critic_hidden() const;
  torch::Tensor support() const;
  double alpha() const;
  double target_entropy() const;

  // tanh(mean) of the actor at raw obs [B, obs_dim] -> [B, act_dim]; no gradient.
  torch::Tensor deterministic_action(const torch::Tensor& obs) const;
  // The actor's outputs [B, 2 * act_dim] (mean, then unclamped log-std) at raw obs; no gradient.
  torch::Tensor actor_output(const torch::Tensor& obs) const;
  // The critics' logits [2, B, num_atoms] for raw obs and actions; no gradient.
  torch::Tensor critic_logits(const torch::Tensor& obs, const torch::Tensor& actions) const;
  // Live parameter tensors (tests and diagnostics). Actor: per layer weight [out, in], bias
  // [out]. Critics, both in one tensor each, per layer: weight [2, in, out], bias [2, 1, out] and,
  // for a hidden layer with fastsac.critic_layer_norm, the layer norm's scale and shift [2, 1, out].
  std::vector<torch::Tensor> actor_parameters() const;
  std::vector<torch::Tensor> critic_parameters() const;
  std::vector<torch::Tensor> target_critic_parameters() const;

  // DIR/fastsac.pt: actor, critics, target critics, the temperature, the three optimizer states,
  // the observation moments, the update count and the last actor loss; written to a temporary file
  // and renamed. load() throws std::runtime_error naming the file and the first entry that does
  // not fit this instance.
  void save(const std::string& dir) const;
  void load(const std::string& dir);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace farm
