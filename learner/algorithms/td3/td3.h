// TD3 with a distributional critic, as FastTD3 (Seo et al. 2025, arXiv 2505.22642, and its
// reference implementation): two C51 critics over a fixed support [v_min, v_max], the clipped
// double-Q target taken as the projected distribution of the critic whose expected value is the
// smaller, cross-entropy losses, target policy smoothing, a deterministic tanh actor that steps
// once every policy_delay critic updates, polyak target critics (no target actor: FastTD3 draws
// the next action from the online actor), AdamW, observations normalized by running moments.
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
// actor_loss is -mean of the clipped double Q of the actor's actions at its latest step (0 before
// its first); q_mean averages both critics' expected values on the batch's (obs, action).
struct Td3Stats {
  double critic_loss = 0, actor_loss = 0, q_mean = 0;
  bool actor_stepped = false;  // this update stepped the actor
};

// The C51 support: num_atoms values evenly from v_min to v_max.
torch::Tensor c51_support(int num_atoms, double v_min, double v_max, const torch::TensorOptions& options = {});

// Categorical projection (Bellemare et al. 2017) of the distribution `probs` [B, K] over the
// support, shifted to r + discount * z, back onto the support: each shifted atom, clamped to
// [v_min, v_max], splits its probability between its two neighbouring atoms in proportion to its
// distance from them; one that lands on an atom gives it all. rewards and discount [B] (discount
// gamma^h * (1 - terminated)). Rows of the result sum to what rows of probs sum to.
torch::Tensor c51_projection(const torch::Tensor& probs, const torch::Tensor& rewards, const torch::Tensor& discount,
                             double v_min, double v_max);

// sum_k p_k z_k over the last dimension.
torch::Tensor c51_expected_value(const torch::Tensor& probs, const torch::Tensor& support);

// The critics' targets [2, B, K] from the target critics' next distributions p1, p2 [B, K]: each
// projected (c51_projection); with clipped double Q both critics learn the projection whose
// expected value is the smaller, per row (the second where they are equal, as FastTD3); without,
// each its own.
torch::Tensor td3_critic_target(const torch::Tensor& next_probs1, const torch::Tensor& next_probs2,
                                const torch::Tensor& rewards, const torch::Tensor& discount, double v_min, double v_max,
                                bool clipped_double_q);

// Cross-entropy of the critics' logits [2, B, K] against targets [2, B, K]: the sum over critics of
// -mean_b sum_k target * log_softmax(logits).
torch::Tensor c51_cross_entropy(const torch::Tensor& target, const torch::Tensor& logits);

// What a checkpoint of an actor and twin C51 critics records of them, and a file must match to be
// loaded: "meta" (observation and action sizes, atoms, the actor's hidden sizes, -1, the
// critics') and "support" (v_min, v_max). check_c51_record throws std::runtime_error
// "<section> checkpoint FILE: ..." naming what differs; `section` is the config section ("td3").
struct C51Record {
  int obs_dim = 0, act_dim = 0, num_atoms = 0;
  std::vector<int> hidden, critic_hidden;
  double v_min = 0, v_max = 0;
};
void write_c51_record(torch::serialize::OutputArchive& root, const C51Record& r);
void check_c51_record(torch::serialize::InputArchive& root, const C51Record& r, const std::string& section,
                      const std::string& file);

class Td3 {
 public:
  // Seeds torch's global generator with `seed` (initial weights and target smoothing noise).
  Td3(const config::Td3Config& cfg, int obs_dim, int act_dim, uint64_t seed);
  ~Td3();
  Td3(Td3&&) noexcept;
  Td3& operator=(Td3&&) noexcept;

  // One critic step, the actor's where its turn comes (every policy_delay-th update), then the
  // polyak step of the target critics. Rows with a horizon h (td3.n_step) bootstrap with gamma^h.
  // Observations are raw: the update normalizes them with the running moments (observe()).
  Td3Stats update(const SampledBatch& batch);
  // Adds rows x obs_dim observations to the running moments (where td3.normalize_observations).
  void observe(const float* obs, int64_t rows);

  // The actor as the workers run it: layout {obs, hidden..., 2*act} relu, squashed-Gaussian head;
  // the mean outputs are the actor's, the log-std outputs the constant log((std_min + std_max) / 2)
  // (zero weights); the observation normalizer where td3.normalize_observations.
  PolicyParams export_policy(uint64_t version) const;
  // The exploration std the exported policy carries.
  double exploration_std() const;

  int64_t updates() const;
  bool on_gpu() const;
  torch::Device device() const;
  int obs_dim() const;
  int act_dim() const;
  const std::vector<int>& hidden() const;
  const std::vector<int>& critic_hidden() const;
  torch::Tensor support() const;

  // tanh(actor(normalized obs)) for raw obs [B, obs_dim] -> [B, act_dim]; no gradient.
  torch::Tensor deterministic_action(const torch::Tensor& obs) const;
  // The critics' logits [2, B, num_atoms] for raw obs and actions; no gradient.
  torch::Tensor critic_logits(const torch::Tensor& obs, const torch::Tensor& actions) const;
  // Live parameter tensors (tests and diagnostics). Actor: per layer weight [out, in], bias
  // [out]. Critics, both in one tensor per layer: weight [2, in, out], bias [2, 1, out].
  std::vector<torch::Tensor> actor_parameters() const;
  std::vector<torch::Tensor> critic_parameters() const;
  std::vector<torch::Tensor> target_critic_parameters() const;

  // DIR/td3.pt: actor, critics, target critics, both optimizer states, the observation moments,
  // the update count and the last actor loss; written to a temporary file and renamed. load()
  // throws std::runtime_error naming the file and the first entry that does not fit this instance.
  void save(const std::string& dir) const;
  void load(const std::string& dir);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace farm
