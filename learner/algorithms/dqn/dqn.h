// Double DQN (van Hasselt, Guez and Silver 2016) with a target network, for tasks with discrete
// actions. Losses and update order follow stable-baselines3's DQN (Huber loss, gradient-norm
// clipping, hard target copies), which the mobile-robots paper trains its Jetbot with, so its hyperparameters
// (mobile-robots paper table 3) apply; the target is the double-Q one unless dqn.double_q is off.
// Actions in a batch are the action index stored as one float. For large batches on a GPU
// (dqn.replay_on_device, dqn.matmul_dtype, dqn.lr_reference_batch): minibatches drawn where the
// networks train, several updates queued per call with their figures read back once.
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

struct DqnStats {
  double loss = 0;    // Huber loss of the update
  double q_mean = 0;  // mean Q(s, a) of the batch's actions
  double target_mean = 0;
};

// Bellman targets [B] from next-state Q values [B, A] of the online and the target network:
// double: r + gamma^h (1 - terminated) Q_target(s', argmax_a Q_online(s', a));
// plain:  r + gamma^h (1 - terminated) max_a Q_target(s', a),
// h the rows' horizon [B] (multi-step returns); an undefined `horizon` means h = 1.
torch::Tensor dqn_target(const torch::Tensor& reward, const torch::Tensor& terminated,
                         const torch::Tensor& next_q_online, const torch::Tensor& next_q_target, double gamma,
                         bool double_q, const torch::Tensor& horizon = {});

// Exploration probability after `env_steps` environment steps: falls linearly from
// exploration_initial_eps to exploration_final_eps over exploration_fraction *
// schedule_env_steps steps, then stays (sb3's linear schedule).
double dqn_epsilon(const config::DqnConfig& cfg, int64_t env_steps);

class Dqn {
 public:
  // Seeds torch's global generator with `seed` (initial weights).
  Dqn(const config::DqnConfig& cfg, int obs_dim, int num_actions, uint64_t seed);
  ~Dqn();
  Dqn(Dqn&&) noexcept;
  Dqn& operator=(Dqn&&) noexcept;

  // One gradient step on the batch; copies the online network into the target network every
  // target_update_updates updates.
  DqnStats update(const SampledBatch& batch);
  // n updates in a row, each on the batch next_batch() returns: the same as n calls of
  // update(next_batch()), except that the figures of all n are read back once, after the last (on
  // a GPU one synchronization per call instead of one per update). Returns them oldest first.
  std::vector<DqnStats> update_n(int n, const std::function<SampledBatch()>& next_batch);
  // n updates as update_n's, each on `batch` rows drawn from `replay` as DeviceReplay::sample draws
  // them (torch's generator of the replay's device). In a CUDA graph the draw is inside the graph,
  // so the host only queues replays. Throws std::invalid_argument where `replay` is not on this
  // Dqn's device, std::logic_error where it is empty.
  std::vector<DqnStats> update_n_from(int n, int64_t batch, const DeviceReplay& replay);

  // The learning rate as learning_rate * factor from the next update on (dqn.max_step_scale: a
  // batch s times as large takes sqrt(s)); a finite factor > 0, else std::invalid_argument. Kept
  // across load(), which does not restore a saved rate.
  void scale_learning_rate(double factor);
  double learning_rate() const;  // the rate updates take now

  // The learner's environment step count, which sets the exploration of exported policies.
  void set_env_steps(int64_t env_steps) { env_steps_ = env_steps; }
  int64_t env_steps() const { return env_steps_; }
  double epsilon() const;

  // The online Q network as the workers run it: layout {obs, hidden..., num_actions} relu,
  // discrete-Q head, epsilon for the current env step count.
  PolicyParams export_policy(uint64_t version) const;

  int64_t updates() const;
  // True when updates replay a captured CUDA graph: dqn.device a GPU, dqn.cuda_graph, and a
  // learner built against a CUDA LibTorch.
  bool uses_cuda_graph() const;
  bool on_gpu() const;  // the Q networks train on a CUDA device
  torch::Device device() const;
  int obs_dim() const;
  int num_actions() const;
  const std::vector<int>& hidden() const;

  // Q values [B, A] of the online network, on obs's device; no gradient.
  torch::Tensor q_values(const torch::Tensor& obs) const;
  // Per layer weight [out, in], bias [out].
  std::vector<torch::Tensor> online_parameters() const;
  std::vector<torch::Tensor> target_parameters() const;

  // DIR/dqn.pt: online and target networks, optimizer state, update count; written to a
  // temporary file and renamed. load() throws std::runtime_error naming the file and what does
  // not match this instance.
  void save(const std::string& dir) const;
  void load(const std::string& dir);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  int64_t env_steps_ = 0;
};

}  // namespace farm
