// SAC as the learner runs it: the networks (sac.h) over the shared replay storage (replay_store.h).
#include <cmath>
#include <filesystem>
#include <limits>
#include <stdexcept>

#include "algorithm.h"
#include "replay_store.h"
#include "sac.h"
#include "step_size.h"
#include "task_spec.h"

namespace farm {

namespace {

class SacAlgorithm final : public Algorithm {
 public:
  SacAlgorithm(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec)
      : cfg_(cfg.sac()),
        sac_(cfg.sac(), spec.obs_dim, spec.act_dim, cfg.seed()),
        replay_(cfg_.buffer_size(), spec.obs_dim, spec.act_dim, cfg_.gamma(), cfg_.n_step(), cfg.seed(),
                draws_on_device() ? std::optional<torch::Device>(sac_.device()) : std::nullopt) {}

  std::string name() const override { return "sac"; }
  std::string describe() const override {
    std::string step = step_phrase("sac", cfg_.n_step(), cfg_.max_step_scale(), sac_.on_gpu());
    if (sac_.uses_cuda_graph())
      step += sac_.uses_fused_kernels() ? ", CUDA graph with fused kernels" : ", CUDA graph of torch's ops";
    if (replay_.on_device()) step += ", minibatches drawn on the GPU";
    step += lr_decay_phrase(cfg_.lr_decay_updates(), cfg_.lr_decay_to());
    if (cfg_.policy_average_tau() > 0)
      step += ", publishing a Polyak average of the actor (tau " + std::to_string(cfg_.policy_average_tau()) + ")";
    return "SAC " + sac_.export_policy(0).layout.describe() + " actor" + step;
  }

  void insert(const Batch& b) override { replay_.insert(b); }
  Holding holding() const override { return {replay_.size(), replay_.capacity()}; }
  int64_t ready() const override { return replay_.size() >= batch_size() ? std::numeric_limits<int64_t>::max() : 0; }
  std::vector<UpdateFigures> update(int n, uint64_t) override {
    apply_rates();
    if (const DeviceReplay* d = replay_.on_device()) return figures(sac_.update_n_from(n, batch_size(), *d));
    return figures(sac_.update_n(n, [this] { return replay_.sample(batch_size()); }));
  }
  std::vector<UpdateFigures> finish() override { return figures(sac_.finish_updates()); }
  int64_t updates() const override { return sac_.updates(); }
  // On a GPU only: there a batch of 1024 costs little more than one of 256, while on a CPU it
  // costs 2.3-3.4 times as much.
  int max_step_scale() const override { return sac_.on_gpu() ? cfg_.max_step_scale() : 1; }
  void set_step_scale(int s) override {
    step_scale_ = s;
    apply_rates();
  }

  PolicyParams policy(uint64_t version) const override { return sac_.export_policy(version); }
  void save_networks(const std::string& dir) const override {
    std::filesystem::create_directories(std::filesystem::path(dir) / "sac");
    sac_.save((std::filesystem::path(dir) / "sac").string());
  }
  void save(const std::string& dir) const override {
    save_networks(dir);
    replay_.save(dir);
  }
  void load_networks(const std::string& dir) override { sac_.load((std::filesystem::path(dir) / "sac").string()); }
  void load(const std::string& dir) override {
    load_networks(dir);
    replay_.load(dir);
  }
  void to_manifest(config::CheckpointManifest& m) const override { replay_.to_manifest(m); }
  std::string from_manifest(const config::CheckpointManifest& m) override {
    replay_.from_manifest(m);  // after the networks' constructor seeded LibTorch
    return std::to_string(sac_.updates()) + " updates, buffer " + std::to_string(replay_.size());
  }

  int batch_size() const { return cfg_.batch_size() * step_scale_; }

 private:
  // The rates for the step scale and the schedule (sac.lr_decay_updates) at the updates made; a
  // factor that did not change costs nothing (Sac::scale_learning_rates).
  void apply_rates() {
    sac_.scale_learning_rates(std::sqrt(double(step_scale_)) *
                              lr_decay_factor(cfg_.lr_decay_updates(), cfg_.lr_decay_to(), sac_.updates()));
  }
  bool draws_on_device() const { return cfg_.replay_on_device() && sac_.uses_cuda_graph(); }
  // The figures of updates that have finished, numbered: the last of them is the one before those
  // still running.
  std::vector<UpdateFigures> figures(const std::vector<SacStats>& stats) const {
    std::vector<UpdateFigures> out(stats.size());
    const int64_t first = sac_.updates() - sac_.updates_in_flight() - int64_t(stats.size()) + 1;
    for (size_t k = 0; k < stats.size(); ++k) {
      out[k].update = first + int64_t(k);
      out[k].values = {
          {"critic loss", stats[k].critic_loss}, {"actor loss", stats[k].actor_loss}, {"alpha", stats[k].alpha}};
    }
    return out;
  }

  config::SacConfig cfg_;
  Sac sac_;
  ReplayStore replay_;
  int step_scale_ = 1;
};

}  // namespace

std::unique_ptr<Algorithm> make_sac(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec) {
  if (spec.num_actions > 0) {
    throw std::invalid_argument("algorithm \"sac\" needs continuous actions, but task '" + spec.name + "' has " +
                                std::to_string(spec.num_actions) +
                                " discrete ones (set its scene.discrete_actions: false, or use algorithm \"dqn\")");
  }
  return std::make_unique<SacAlgorithm>(cfg, spec);
}

}  // namespace farm
