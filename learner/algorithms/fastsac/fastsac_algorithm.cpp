// FastSAC as the learner runs it: the networks (fastsac.h) over the shared replay storage
// (net_replay_algorithm.h).
#include "config_validator.h"
#include "fastsac.h"
#include "net_replay_algorithm.h"
#include "step_size.h"
#include "task_spec.h"

namespace farm {

namespace {

class FastSacAlgorithm final : public NetReplayAlgorithm<FastSac> {
 public:
  FastSacAlgorithm(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec)
      : NetReplayAlgorithm("fastsac", FastSac(cfg.fastsac(), spec.obs_dim, spec.act_dim, cfg.seed()),
                           cfg.fastsac().batch_size(), cfg.fastsac().buffer_size(), spec.obs_dim, spec.act_dim,
                           cfg.fastsac().gamma(), cfg.fastsac().n_step(), cfg.seed()),
        cfg_(cfg.fastsac()) {}

  std::string describe() const override {
    using config_checks::num;
    std::string s = "FastSAC " + net().export_policy(0).layout.describe() + " actor, twin C51 critics of " +
                    num(cfg_.num_atoms()) + " atoms in [" + num(cfg_.v_min()) + ", " + num(cfg_.v_max()) + "]";
    if (cfg_.critic_layer_norm()) s += " with layer norm";
    s += ", temperature from " + num(cfg_.initial_alpha());
    s += cfg_.autotune() ? " toward entropy " + num(net().target_entropy()) : " (fixed)";
    return s + step_phrase("fastsac", cfg_.n_step(), 1, net().on_gpu());
  }

 protected:
  std::vector<std::pair<std::string, double>> figures(const FastSacStats& st) const override {
    return {{"critic loss", st.critic_loss},
            {"actor loss", st.actor_loss},
            {"alpha", st.alpha},
            {"entropy", st.entropy},
            {"q mean", st.q_mean}};
  }

 private:
  config::FastSacConfig cfg_;
};

}  // namespace

std::unique_ptr<Algorithm> make_fastsac(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec) {
  require_continuous_actions("fastsac", spec);
  return std::make_unique<FastSacAlgorithm>(cfg, spec);
}

}  // namespace farm
