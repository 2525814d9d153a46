// Soft Actor-Critic with automatic entropy temperature (the 2018 "applications" version),
// following the update order and losses of stable-baselines3's SAC so that its published
// hyperparameters apply.
#pragma once

#include <torch/torch.h>

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "farm_config.pb.h"
#include "mlp.h"
#include "replay_buffer.h"

namespace farm {

class DeviceReplay;

// One update's numbers. critic_loss is sb3's 0.5 * (mse(Q1) + mse(Q2)); alpha is the temperature
// the losses used (the one before this update's own alpha step); entropy is -mean log_prob of the
// policy's samples on the batch; q_mean averages both critics on the batch's (obs, action).
struct SacStats {
  double critic_loss = 0, actor_loss = 0, alpha = 0, alpha_loss = 0, entropy = 0, q_mean = 0;
};

// Soft Bellman target: r + gamma * (1 - terminated) * (min(q1, q2) - alpha * next_log_prob).
// Truncated (time-limit) transitions are not terminated and keep the bootstrap.
torch::Tensor sac_critic_target(const torch::Tensor& reward, const torch::Tensor& terminated,
                                const torch::Tensor& next_q1, const torch::Tensor& next_q2,
                                const torch::Tensor& next_log_prob, double alpha, double gamma);

// -(log_alpha * (log_prob + target_entropy).detach()).mean(): its gradient raises alpha while the
// policy entropy (-log_prob) is below the target and lowers it above.
torch::Tensor sac_temperature_loss(const torch::Tensor& log_alpha, const torch::Tensor& log_prob,
                                   double target_entropy);

// Log-density of a = tanh(pre_tanh) with pre_tanh ~ N(mean, exp(log_std)), summed over the last
// dimension: [..., act] -> [...]. Uses the log(1 - tanh^2 + 1e-6) change-of-variables term.
torch::Tensor squashed_gaussian_log_prob(const torch::Tensor& mean, const torch::Tensor& log_std,
                                         const torch::Tensor& pre_tanh);

class Sac {
 public:
  // Seeds torch's global generator with `seed` (initial weights and exploration noise).
  Sac(const config::SacConfig& cfg, int obs_dim, int act_dim, uint64_t seed);
  ~Sac();
  Sac(Sac&&) noexcept;
  Sac& operator=(Sac&&) noexcept;

  // One gradient step of temperature, critics and actor, then the polyak target update. A row
  // with a horizon h (multi-step returns, sac.n_step) bootstraps with gamma^h (fold_horizon).
  SacStats update(const SampledBatch& batch);
  // n updates in a row, each on the batch next_batch() returns: the same as n calls of
  // update(next_batch()). Returns the figures of the updates that have run, oldest first. Without
  // a CUDA graph those are these n. With one, the replays are queued on the GPU and next_batch()
  // samples the following batch on the host while the queued ones run; the call returns without
  // waiting for the last of them, so the GPU keeps working while the caller does other host work
  // (the learner: the bus), and their figures come with a later call or finish_updates().
  // updates() counts them from the moment they are queued.
  std::vector<SacStats> update_n(int n, const std::function<SampledBatch()>& next_batch);
  // n updates as update_n's, each on `batch` rows drawn from `replay` (on this Sac's device) as
  // DeviceReplay::sample draws them. With a CUDA graph the draw is inside the graph, so the host
  // only queues replays; `replay` must outlive the updates queued from it. Throws
  // std::invalid_argument when `replay` is on another device.
  std::vector<SacStats> update_n_from(int n, int64_t batch, const DeviceReplay& replay);
  // Updates queued by update_n whose figures have not been returned yet.
  int64_t updates_in_flight() const;
  // Waits for those and returns their figures, oldest first (none without a CUDA graph).
  std::vector<SacStats> finish_updates();

  // The actor as the workers run it: layout {obs, hidden..., 2*act} relu, squashed-Gaussian head,
  // no observation normalizer.
  PolicyParams export_policy(uint64_t version) const;

  int64_t updates() const;
  // The actor's, critics' and temperature's learning rates as sac.actor_lr, sac.critic_lr and
  // sac.alpha_lr times `factor`, from the next update on; kept over load(). factor must be > 0.
  void scale_learning_rates(double factor);
  double learning_rate_scale() const;
  // True when updates replay a captured CUDA graph: a CUDA device, sac.cuda_graph, and a learner
  // built against a CUDA LibTorch. Same arithmetic as the eager path, a few hundred kernel launches
  // fewer per update.
  bool uses_cuda_graph() const;
  // True when that graph takes the fused kernels (sac.cuda_fused_kernels, a learner built with a
  // CUDA compiler) for the policy's sample, the critics' target and the actor's loss.
  bool uses_fused_kernels() const;
  bool on_gpu() const;  // the networks train on a CUDA device
  torch::Device device() const;
  int obs_dim() const;
  int act_dim() const;
  const std::vector<int>& hidden() const;
  double alpha() const;
  double target_entropy() const;

  // tanh(mean) for obs [B, obs_dim] -> [B, act_dim]; no gradient.
  torch::Tensor deterministic_action(const torch::Tensor& obs) const;
  // Live parameter tensors, in a fixed order (for tests and diagnostics; do not resize them).
  // Actor: per layer weight [out, in], bias [out]. Critics, both stacked in one tensor per layer:
  // weight [2, in, out], bias [2, 1, out].
  std::vector<torch::Tensor> actor_parameters() const;
  std::vector<torch::Tensor> critic_parameters() const;
  std::vector<torch::Tensor> target_critic_parameters() const;

  // DIR/sac.pt: actor, critics, target critics, the three optimizer states, log_alpha and the
  // update count; written to a temporary file and renamed. load() throws std::runtime_error naming
  // the file and the first entry whose shape (or network sizes) does not match this instance.
  void save(const std::string& dir) const;
  void load(const std::string& dir);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace farm
