// An Algorithm of one network class over the shared replay storage (replay_store.h), one update a
// minibatch drawn on the host: what the TD3 and FastSAC learners share. The network class has
// observe(obs, rows) (running observation moments), update(SampledBatch) returning its figures,
// updates(), export_policy(version), save(dir) and load(dir); each learner adds its name, its
// start line and the figures it logs of an update.
#pragma once

#include <algorithm>
#include <filesystem>
#include <limits>
#include <optional>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "algorithm.h"
#include "replay_store.h"
#include "task_spec.h"

namespace farm {

// Throws std::invalid_argument naming `algorithm` where the task's actions are discrete.
inline void require_continuous_actions(const std::string& algorithm, const robots::TaskSpec& spec) {
  if (spec.num_actions > 0)
    throw std::invalid_argument("algorithm \"" + algorithm + "\" needs continuous actions, but task '" + spec.name +
                                "' has " + std::to_string(spec.num_actions) +
                                " discrete ones (set its scene.discrete_actions: false, or use algorithm \"dqn\")");
}

template <class Net>
class NetReplayAlgorithm : public Algorithm {
 public:
  using Stats = decltype(std::declval<Net&>().update(std::declval<const SampledBatch&>()));

  // `net` is built first (its constructor seeds LibTorch), then the replay storage of `buffer_size`
  // rows folded to `n_step` returns.
  NetReplayAlgorithm(std::string name, Net&& net, int batch_size, int64_t buffer_size, int obs_dim, int act_dim,
                     double gamma, int n_step, uint64_t seed)
      : net_(std::move(net)),
        replay_(buffer_size, obs_dim, act_dim, gamma, n_step, seed, std::nullopt),
        name_(std::move(name)),
        batch_size_(batch_size) {}

  std::string name() const override { return name_; }
  void insert(const Batch& b) override {
    net_.observe(b.rows->obs.data(), b.rows->n);  // before the rows are folded: every step's observation once
    replay_.insert(b);
  }
  Holding holding() const override { return {replay_.size(), replay_.capacity()}; }
  int64_t ready() const override { return replay_.size() >= batch_size_ ? std::numeric_limits<int64_t>::max() : 0; }
  std::vector<UpdateFigures> update(int n, uint64_t) override {
    std::vector<UpdateFigures> out(size_t(std::max(n, 0)));
    for (auto& f : out) {
      const Stats st = net_.update(replay_.sample(batch_size_));
      f.update = net_.updates();
      f.values = figures(st);
    }
    return out;
  }
  int64_t updates() const override { return net_.updates(); }

  PolicyParams policy(uint64_t version) const override { return net_.export_policy(version); }
  void save_networks(const std::string& dir) const override { net_.save(folder(dir)); }
  void save(const std::string& dir) const override {
    save_networks(dir);
    replay_.save(dir);
  }
  void load_networks(const std::string& dir) override { net_.load(folder(dir)); }
  void load(const std::string& dir) override {
    load_networks(dir);
    replay_.load(dir);
  }
  void to_manifest(config::CheckpointManifest& m) const override { replay_.to_manifest(m); }
  std::string from_manifest(const config::CheckpointManifest& m) override {
    replay_.from_manifest(m);  // after the networks' constructor seeded LibTorch
    return std::to_string(net_.updates()) + " updates, buffer " + std::to_string(replay_.size());
  }

 protected:
  // An update's figures, by name, in the order the log and the CSV take them.
  virtual std::vector<std::pair<std::string, double>> figures(const Stats& st) const = 0;
  const Net& net() const { return net_; }

 private:
  std::string folder(const std::string& dir) const { return (std::filesystem::path(dir) / name_).string(); }

  Net net_;
  ReplayStore replay_;
  std::string name_;
  int batch_size_;
};

}  // namespace farm
