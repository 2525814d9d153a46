// The policy an experiment's learner hands its workers, from the config alone (policy_shape.h).
#include "policy_shape.h"

#include <cmath>
#include <random>
#include <stdexcept>
#include <string>

#include "config.h"

namespace farm {

std::vector<int> dqn_hidden(const config::DqnConfig& dqn) {
  if (dqn.hidden_size() == 0) return {64, 64};  // sb3 DQN net_arch
  return {dqn.hidden().begin(), dqn.hidden().end()};
}

std::vector<int> ppo_hidden(const config::PpoConfig& ppo) {
  if (ppo.hidden_size() == 0) return {64, 64};
  return {ppo.hidden().begin(), ppo.hidden().end()};
}

std::vector<int> td3_hidden(const config::Td3Config& td3) {
  if (td3.hidden_size() == 0) return {512, 256, 128};  // FastTD3 actor_hidden_dim 512: 512, /2, /4
  return {td3.hidden().begin(), td3.hidden().end()};
}

std::vector<int> td3_critic_hidden(const config::Td3Config& td3) {
  if (td3.critic_hidden_size() == 0) return {1024, 512, 256};  // FastTD3 critic_hidden_dim 1024: 1024, /2, /4
  return {td3.critic_hidden().begin(), td3.critic_hidden().end()};
}

std::vector<int> fastsac_hidden(const config::FastSacConfig& fastsac) {
  if (fastsac.hidden_size() == 0) return {512, 256, 128};  // FastSAC actor_hidden_dim 512: 512, /2, /4
  return {fastsac.hidden().begin(), fastsac.hidden().end()};
}

std::vector<int> fastsac_critic_hidden(const config::FastSacConfig& fastsac) {
  if (fastsac.critic_hidden_size() == 0) return {768, 384, 192};  // FastSAC critic_hidden_dim 768: 768, /2, /4
  return {fastsac.critic_hidden().begin(), fastsac.critic_hidden().end()};
}

namespace {

MlpLayout layout(int in, const std::vector<int>& hidden, int out, Activation activation) {
  MlpLayout l;
  l.activation = activation;
  l.sizes.push_back(in);
  l.sizes.insert(l.sizes.end(), hidden.begin(), hidden.end());
  l.sizes.push_back(out);
  return l;
}

}  // namespace

PolicyParams sac_policy_shape(const config::SacConfig& sac, int obs_dim, int act_dim) {
  if (sac.activation() != "relu" && sac.activation() != "tanh")
    throw std::invalid_argument("sac.activation must be \"relu\" or \"tanh\", got \"" + sac.activation() + "\"");
  PolicyParams p;
  p.head = PolicyHead::kSquashedGaussian;
  p.layout =
      layout(obs_dim, sac_hidden(sac), 2 * act_dim, sac.activation() == "tanh" ? Activation::kTanh : Activation::kRelu);
  p.log_std_min = float(sac.log_std_min());
  p.log_std_max = float(sac.log_std_max());
  return p;
}

PolicyParams dqn_policy_shape(int obs_dim, int num_actions, const config::DqnConfig& dqn) {
  PolicyParams p;
  p.head = PolicyHead::kDiscreteQ;
  p.layout = layout(obs_dim, dqn_hidden(dqn), num_actions, Activation::kRelu);
  return p;
}

PolicyParams ppo_policy_shape(const config::PpoConfig& ppo, int obs_dim, int act_dim) {
  PolicyParams p;
  p.head = PolicyHead::kGaussian;
  p.layout = layout(obs_dim, ppo_hidden(ppo), act_dim, activation_from_name(ppo.activation()));
  p.log_std_min = float(ppo.log_std_min());
  p.log_std_max = float(ppo.log_std_max());
  p.log_std.assign(size_t(act_dim), float(ppo.initial_log_std()));
  if (ppo.normalize_observations()) {
    p.obs_mean.assign(size_t(obs_dim), 0.f);
    p.obs_std.assign(size_t(obs_dim), 1.f);
  }
  return p;
}

PolicyParams td3_policy_shape(const config::Td3Config& td3, int obs_dim, int act_dim) {
  PolicyParams p;
  p.head = PolicyHead::kSquashedGaussian;
  p.layout = layout(obs_dim, td3_hidden(td3), 2 * act_dim, Activation::kRelu);
  if (td3.normalize_observations()) {
    p.obs_mean.assign(size_t(obs_dim), 0.f);
    p.obs_std.assign(size_t(obs_dim), 1.f);
  }
  return p;
}

PolicyParams fastsac_policy_shape(const config::FastSacConfig& fastsac, int obs_dim, int act_dim) {
  PolicyParams p;
  p.head = PolicyHead::kSquashedGaussian;
  p.layout = layout(obs_dim, fastsac_hidden(fastsac), 2 * act_dim, activation_from_name(fastsac.activation()));
  p.log_std_min = float(fastsac.log_std_min());
  p.log_std_max = float(fastsac.log_std_max());
  if (fastsac.normalize_observations()) {
    p.obs_mean.assign(size_t(obs_dim), 0.f);
    p.obs_std.assign(size_t(obs_dim), 1.f);
  }
  return p;
}

PolicyParams policy_shape(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec) {
  const std::string& a = cfg.algorithm();
  if (a == "sac") return sac_policy_shape(cfg.sac(), spec.obs_dim, spec.act_dim);
  if (a == "dqn") {
    if (spec.num_actions <= 0)
      throw std::invalid_argument("algorithm 'dqn' needs a task with discrete actions; task '" + spec.name +
                                  "' has continuous ones");
    return dqn_policy_shape(spec.obs_dim, spec.num_actions, cfg.dqn());
  }
  if (a == "ppo") return ppo_policy_shape(cfg.ppo(), spec.obs_dim, spec.act_dim);
  if (a == "td3") return td3_policy_shape(cfg.td3(), spec.obs_dim, spec.act_dim);
  if (a == "fastsac") return fastsac_policy_shape(cfg.fastsac(), spec.obs_dim, spec.act_dim);
  throw std::invalid_argument("no policy shape for algorithm '" + a + "' (known: sac, dqn, ppo, td3, fastsac)");
}

PolicyParams untrained_policy(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec) {
  PolicyParams p = policy_shape(cfg, spec);
  p.layout.check();
  std::mt19937_64 rng(cfg.seed());
  const auto& s = p.layout.sizes;
  p.params.reserve(p.layout.num_params());
  for (size_t l = 0; l + 1 < s.size(); ++l) {
    const float bound = 1.f / std::sqrt(float(s[l]));
    std::uniform_real_distribution<float> u(-bound, bound);
    for (int i = 0; i < s[l + 1] * s[l] + s[l + 1]; ++i) p.params.push_back(u(rng));  // weight [out x in], bias
  }
  return p;
}

}  // namespace farm
