// The replay storage SAC and DQN share: the workers' rows, folded to n-step returns (fold_n_step),
// in a ring buffer on the host, which checkpoints hold, and, where updates draw their own
// minibatches on a GPU (sac.replay_on_device), the same rows there (DeviceReplay); minibatches
// drawn on the host with a generator seeded from the experiment's seed.
#pragma once

#include <torch/torch.h>

#include <cstdint>
#include <memory>
#include <optional>
#include <random>
#include <string>

#include "batch.h"
#include "device_replay.h"
#include "farm_config.pb.h"
#include "replay_buffer.h"

namespace farm {

class ReplayStore {
 public:
  ReplayStore(int64_t capacity, int obs_dim, int act_dim, double gamma, int n_step, uint64_t seed,
              std::optional<torch::Device> device);
  // Folds the batch's rows to n-step returns (in place) and stores them.
  void insert(const Batch& b);
  SampledBatch sample(int batch_size) { return host_.sample(batch_size, rng_); }
  // The copy on the updates' device; null where the host samples.
  const DeviceReplay* on_device() const { return device_.get(); }
  int64_t size() const { return host_.size(); }
  int64_t capacity() const { return host_.capacity(); }
  // DIR/replay.pt; load() also refills the device copy. has_saved: whether DIR holds one.
  void save(const std::string& dir) const;
  void load(const std::string& dir);
  static bool has_saved(const std::string& dir);
  // The sampler's state (and LibTorch's CPU generator) in a checkpoint's manifest.
  void to_manifest(config::CheckpointManifest& m) const;
  void from_manifest(const config::CheckpointManifest& m);

 private:
  ReplayBuffer host_;
  std::unique_ptr<DeviceReplay> device_;
  std::mt19937_64 rng_;
  double gamma_;
  int n_step_;
};

}  // namespace farm
