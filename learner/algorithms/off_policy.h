// The replay-buffer driver's view of an off-policy algorithm: SAC for continuous actions, DQN for
// discrete ones, chosen by the experiment's `algorithm`. The driver feeds replay minibatches,
// publishes exported policies, and paces updates with the algorithm's own limits.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "device_replay.h"
#include "farm_config.pb.h"
#include "mlp.h"
#include "replay_buffer.h"
#include "task_spec.h"

namespace farm {

// One update's figures in the learner log's columns: SAC fills all three; DQN reports its TD
// loss as critic_loss and the current epsilon in place of alpha.
struct OffPolicyStats {
  double critic_loss = 0, actor_loss = 0, alpha = 0;
};

// Updates the replay driver runs between two looks at the bus, as one OffPolicy::update_n group.
inline constexpr int kUpdatesPerGroup = 8;

class OffPolicy {
 public:
  virtual ~OffPolicy() = default;
  // "sac" or "dqn", also the checkpoint sub-folder.
  virtual std::string name() const = 0;
  // What OffPolicyStats::alpha holds, as messages name it (DQN: "epsilon").
  virtual std::string alpha_name() const { return "alpha"; }
  virtual OffPolicyStats update(const SampledBatch& batch) = 0;
  // n updates on the batches next_batch() returns, in order, and the figures of the updates that
  // have run, oldest first. An adapter whose updates can be queued on a device (SAC's CUDA graph)
  // overrides this and may return before the last of them have run: their figures come with a
  // later call or with finish_updates(). The default calls update() n times.
  virtual std::vector<OffPolicyStats> update_n(int n, const std::function<SampledBatch()>& next_batch) {
    std::vector<OffPolicyStats> out;
    out.reserve(n);
    for (int i = 0; i < n; ++i) out.push_back(update(next_batch()));
    return out;
  }
  // Where the adapter's updates draw their minibatches themselves, on the device they run on (SAC's
  // CUDA graph with sac.replay_on_device): that device, on which the driver keeps a DeviceReplay
  // copy of its buffer and calls update_n_from instead of update_n. None: the host samples.
  virtual std::optional<torch::Device> replay_device() const { return std::nullopt; }
  // n updates as update_n's, each on batch_size() rows drawn from `replay`.
  virtual std::vector<OffPolicyStats> update_n_from(int /*n*/, const DeviceReplay& /*replay*/) {
    throw std::logic_error(name() + ": no updates from a replay on the device");
  }
  // Updates counted in updates() whose figures update_n has not returned yet.
  virtual int64_t updates_in_flight() const { return 0; }
  // Waits for those and returns their figures, oldest first.
  virtual std::vector<OffPolicyStats> finish_updates() { return {}; }
  virtual PolicyParams export_policy(uint64_t version) const = 0;
  virtual int64_t updates() const = 0;
  // Environment steps received so far (DQN's exploration schedule follows it).
  virtual void set_env_steps(int64_t) {}
  virtual void save(const std::string& dir) const = 0;
  virtual void load(const std::string& dir) = 0;
  // Pacing, from the algorithm's config section.
  virtual int batch_size() const = 0;
  virtual int64_t buffer_size() const = 0;
  virtual int64_t learning_starts() const = 0;
  virtual double max_updates_per_step() const = 0;
  virtual int publish_every_updates() const = 0;
  // A larger step when the data outrun the updates (sac.max_step_scale): the most the driver may
  // scale it by, the scale in use, and the scale to take from now on (SAC: batch_size() times s,
  // learning rates times sqrt(s)). An algorithm without it keeps 1.
  virtual int max_step_scale() const { return 1; }
  virtual int step_scale() const { return 1; }
  virtual void set_step_scale(int /*s*/) {}
  // Multi-step returns: replay rows are folded to this many steps (fold_n_step) before they are
  // stored; 1 keeps one-step rows.
  virtual int n_step() const { return 1; }
  virtual double gamma() const = 0;
  // One line for the start-up log, e.g. "SAC 20-256-256-4 relu actor".
  virtual std::string describe() const = 0;
};

// The adapters; each throws std::invalid_argument when the task's action space does not fit.
std::unique_ptr<OffPolicy> make_sac(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec);
std::unique_ptr<OffPolicy> make_dqn(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec);

// The adapter of cfg.algorithm(), looked up in the algorithm registry (registry.cpp). Throws
// std::invalid_argument when the algorithm is unknown, not off-policy, or does not fit the task.
std::unique_ptr<OffPolicy> make_off_policy(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec);

// sac.max_step_scale's rule, from the scale in use and r, the updates the data allowed over the
// last window per update made (max_updates_per_step x env steps received / updates made): up to
// the power of 2 nearest r on a log scale (s where r is s / sqrt(2) or more), down to it once r
// falls below 0.8 s / sqrt(2) for the scale s in use (the margin keeps a scale from flapping on a
// ratio near a band's edge), never past `most` nor below 1.
int next_step_scale(int current, double r, int most);

class Algorithm;
// The replay-buffer driver (off_policy_algorithm.cpp) running an adapter in the learner.
std::unique_ptr<Algorithm> make_off_policy_algorithm(std::unique_ptr<OffPolicy> algo,
                                                     const config::ExperimentConfig& cfg, const robots::TaskSpec& spec);

}  // namespace farm
