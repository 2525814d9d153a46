// TD3 as the learner runs it: the networks (td3.h) over the shared replay storage
// (net_replay_algorithm.h).
#include "config_validator.h"
#include "net_replay_algorithm.h"
#include "step_size.h"
#include "task_spec.h"
#include "td3.h"

namespace farm {

namespace {

class Td3Algorithm final : public NetReplayAlgorithm<Td3> {
 public:
  Td3Algorithm(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec)
      : NetReplayAlgorithm("td3", Td3(cfg.td3(), spec.obs_dim, spec.act_dim, cfg.seed()), cfg.td3().batch_size(),
                           cfg.td3().buffer_size(), spec.obs_dim, spec.act_dim, cfg.td3().gamma(), cfg.td3().n_step(),
                           cfg.seed()),
        cfg_(cfg.td3()) {}

  std::string describe() const override {
    using config_checks::num;
    std::string s = "TD3 " + net().export_policy(0).layout.describe() + " actor, twin C51 critics of " +
                    num(cfg_.num_atoms()) + " atoms in [" + num(cfg_.v_min()) + ", " + num(cfg_.v_max()) + "]";
    s += ", exploration std " + num(net().exploration_std());
    s += step_phrase("td3", cfg_.n_step(), 1, net().on_gpu());
    return s;
  }

 protected:
  std::vector<std::pair<std::string, double>> figures(const Td3Stats& st) const override {
    return {{"critic loss", st.critic_loss}, {"actor loss", st.actor_loss}, {"q mean", st.q_mean}};
  }

 private:
  config::Td3Config cfg_;
};

}  // namespace

std::unique_ptr<Algorithm> make_td3(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec) {
  require_continuous_actions("td3", spec);
  return std::make_unique<Td3Algorithm>(cfg, spec);
}

}  // namespace farm
