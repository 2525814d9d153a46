// DQN as the learner runs it: the Q networks (dqn.h) over the shared replay storage
// (replay_store.h), its rows also on the GPU where the networks train there (dqn.replay_on_device).
// Exploration follows the env steps inserted; a policy version keeps the epsilon it was first
// exported with, so that one version is one policy.
#include <algorithm>
#include <filesystem>
#include <limits>
#include <optional>
#include <stdexcept>

#include "algorithm.h"
#include "dqn.h"
#include "replay_store.h"
#include "step_size.h"
#include "task_spec.h"

namespace farm {

namespace {

class DqnAlgorithm final : public Algorithm {
 public:
  DqnAlgorithm(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec)
      : cfg_(cfg.dqn()),
        dqn_(cfg.dqn(), spec.obs_dim, spec.num_actions, cfg.seed()),
        replay_(cfg_.buffer_size(), spec.obs_dim, spec.act_dim, cfg_.gamma(), cfg_.n_step(), cfg.seed(),
                draws_on_device() ? std::optional<torch::Device>(dqn_.device()) : std::nullopt) {}

  std::string name() const override { return "dqn"; }
  std::string describe() const override {
    std::string step = step_phrase("dqn", cfg_.n_step(), cfg_.max_step_scale(), dqn_.on_gpu());
    step += batch_lr_phrase(cfg_.batch_size(), cfg_.lr_reference_batch());
    step += lr_decay_phrase(cfg_.lr_decay_updates(), cfg_.lr_decay_to());
    if (dqn_.uses_cuda_graph())
      step += ", CUDA graph";
    else if (dqn_.on_gpu())
      step += ", on the GPU";
    if (replay_.on_device()) step += ", minibatches drawn on the GPU";
    if (cfg_.matmul_dtype() != "float32") step += ", " + cfg_.matmul_dtype() + " products";
    return std::string(cfg_.double_q() ? "double DQN " : "DQN ") + dqn_.export_policy(0).layout.describe() +
           " Q network" + step;
  }

  void insert(const Batch& b) override {
    env_steps_ += b.rows->n;
    replay_.insert(b);
  }
  Holding holding() const override { return {replay_.size(), replay_.capacity()}; }
  int64_t ready() const override { return replay_.size() >= batch_size() ? std::numeric_limits<int64_t>::max() : 0; }
  // n updates queued at once, their figures read back after the last.
  std::vector<UpdateFigures> update(int n, uint64_t) override {
    apply_rate();
    const DeviceReplay* d = replay_.on_device();
    const std::vector<DqnStats> stats =
        d ? dqn_.update_n_from(n, batch_size(), *d) : dqn_.update_n(n, [this] { return replay_.sample(batch_size()); });
    std::vector<UpdateFigures> out(stats.size());
    const int64_t first = dqn_.updates() - int64_t(stats.size()) + 1;
    for (size_t k = 0; k < stats.size(); ++k) {
      out[k].update = first + int64_t(k);
      out[k].values = {{"critic loss", stats[k].loss}, {"epsilon", dqn_.epsilon()}};
    }
    return out;
  }
  int64_t updates() const override { return dqn_.updates(); }
  // On a GPU only, as SAC's: there a batch four times as large costs little more (bench_dqn).
  int max_step_scale() const override { return dqn_.on_gpu() ? cfg_.max_step_scale() : 1; }
  void set_step_scale(int s) override {
    step_scale_ = s;
    apply_rate();
  }

  PolicyParams policy(uint64_t version) const override {
    if (version != exported_version_) {
      dqn_.set_env_steps(env_steps_);
      exported_version_ = version;
    }
    return dqn_.export_policy(version);
  }
  void save_networks(const std::string& dir) const override {
    std::filesystem::create_directories(std::filesystem::path(dir) / "dqn");
    dqn_.save((std::filesystem::path(dir) / "dqn").string());
  }
  void save(const std::string& dir) const override {
    save_networks(dir);
    replay_.save(dir);
  }
  void load_networks(const std::string& dir) override {
    dqn_.load((std::filesystem::path(dir) / "dqn").string());
    env_steps_ = dqn_.env_steps();
  }
  void load(const std::string& dir) override {
    load_networks(dir);
    replay_.load(dir);
  }
  void to_manifest(config::CheckpointManifest& m) const override { replay_.to_manifest(m); }
  std::string from_manifest(const config::CheckpointManifest& m) override {
    replay_.from_manifest(m);
    // Every step the checkpoint's accounts hold was inserted; the networks' copy counts only those
    // up to the last version exported before the checkpoint.
    env_steps_ = std::max(env_steps_, int64_t(m.env_steps()));
    return std::to_string(dqn_.updates()) + " updates, buffer " + std::to_string(replay_.size());
  }

 private:
  // The rate for the batch (dqn.lr_reference_batch), the step scale and the schedule
  // (dqn.lr_decay_updates) at the updates made; a factor that did not change costs nothing
  // (Dqn::scale_learning_rate).
  void apply_rate() {
    dqn_.scale_learning_rate(batch_lr_factor(cfg_.batch_size(), step_scale_, cfg_.lr_reference_batch()) *
                             lr_decay_factor(cfg_.lr_decay_updates(), cfg_.lr_decay_to(), dqn_.updates()));
  }
  bool draws_on_device() const { return cfg_.replay_on_device() && dqn_.on_gpu(); }
  int64_t batch_size() const { return int64_t(cfg_.batch_size()) * step_scale_; }

  config::DqnConfig cfg_;
  mutable Dqn dqn_;  // policy() sets the exploration of a new version
  ReplayStore replay_;
  int step_scale_ = 1;     // dqn.max_step_scale's, as the pacing sets it
  int64_t env_steps_ = 0;  // inserted: the exploration schedule's clock
  mutable uint64_t exported_version_ = std::numeric_limits<uint64_t>::max();
};

}  // namespace

std::unique_ptr<Algorithm> make_dqn(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec) {
  if (spec.num_actions == 0) {
    throw std::invalid_argument("algorithm \"dqn\" needs discrete actions, but task '" + spec.name +
                                "' has continuous ones");
  }
  return std::make_unique<DqnAlgorithm>(cfg, spec);
}

}  // namespace farm
