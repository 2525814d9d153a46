// TD3 as the learner runs it: the networks (td3.h) over the shared replay storage (replay_store.h).
#include <cmath>
#include <filesystem>
#include <limits>
#include <stdexcept>

#include "algorithm.h"
#include "config_validator.h"
#include "replay_store.h"
#include "step_size.h"
#include "task_spec.h"
#include "td3.h"

namespace farm {

namespace {

class Td3Algorithm final : public Algorithm {
 public:
  Td3Algorithm(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec)
      : cfg_(cfg.td3()),
        td3_(cfg.td3(), spec.obs_dim, spec.act_dim, cfg.seed()),
        replay_(cfg_.buffer_size(), spec.obs_dim, spec.act_dim, cfg_.gamma(), cfg_.n_step(), cfg.seed(), std::nullopt) {
  }

  std::string name() const override { return "td3"; }
  std::string describe() const override {
    using config_checks::num;
    std::string s = "TD3 " + td3_.export_policy(0).layout.describe() + " actor, twin C51 critics of " +
                    num(cfg_.num_atoms()) + " atoms in [" + num(cfg_.v_min()) + ", " + num(cfg_.v_max()) + "]";
    s += ", exploration std " + num(td3_.exploration_std());
    s += step_phrase("td3", cfg_.n_step(), 1, td3_.on_gpu());
    return s;
  }

  void insert(const Batch& b) override {
    td3_.observe(b.rows->obs.data(), b.rows->n);  // before the rows are folded: every step's observation once
    replay_.insert(b);
  }
  Holding holding() const override { return {replay_.size(), replay_.capacity()}; }
  int64_t ready() const override {
    return replay_.size() >= cfg_.batch_size() ? std::numeric_limits<int64_t>::max() : 0;
  }
  std::vector<UpdateFigures> update(int n, uint64_t) override {
    std::vector<UpdateFigures> out(size_t(std::max(n, 0)));
    for (auto& f : out) {
      const Td3Stats st = td3_.update(replay_.sample(cfg_.batch_size()));
      f.update = td3_.updates();
      f.values = {{"critic loss", st.critic_loss}, {"actor loss", st.actor_loss}, {"q mean", st.q_mean}};
    }
    return out;
  }
  int64_t updates() const override { return td3_.updates(); }

  PolicyParams policy(uint64_t version) const override { return td3_.export_policy(version); }
  void save_networks(const std::string& dir) const override {
    td3_.save((std::filesystem::path(dir) / "td3").string());
  }
  void save(const std::string& dir) const override {
    save_networks(dir);
    replay_.save(dir);
  }
  void load_networks(const std::string& dir) override { td3_.load((std::filesystem::path(dir) / "td3").string()); }
  void load(const std::string& dir) override {
    load_networks(dir);
    replay_.load(dir);
  }
  void to_manifest(config::CheckpointManifest& m) const override { replay_.to_manifest(m); }
  std::string from_manifest(const config::CheckpointManifest& m) override {
    replay_.from_manifest(m);  // after the networks' constructor seeded LibTorch
    return std::to_string(td3_.updates()) + " updates, buffer " + std::to_string(replay_.size());
  }

 private:
  config::Td3Config cfg_;
  Td3 td3_;
  ReplayStore replay_;
};

}  // namespace

std::unique_ptr<Algorithm> make_td3(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec) {
  if (spec.num_actions > 0) {
    throw std::invalid_argument("algorithm \"td3\" needs continuous actions, but task '" + spec.name + "' has " +
                                std::to_string(spec.num_actions) +
                                " discrete ones (set its scene.discrete_actions: false, or use algorithm \"dqn\")");
  }
  return std::make_unique<Td3Algorithm>(cfg, spec);
}

}  // namespace farm
