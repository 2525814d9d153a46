// The policy an experiment's learner hands its workers, from the config alone: the head, the
// network layout and the bounds its algorithm's section gives (no parameters), and an untrained
// policy of that shape. The algorithms export their trained policies in this shape; the programs
// that show a task before training (farm-play --config) build the untrained one without LibTorch.
#pragma once

#include <vector>

#include "farm_config.pb.h"
#include "mlp.h"
#include "task_spec.h"

namespace farm {

// Hidden sizes of the DQN Q network and of the PPO actor and critic (each section's default when
// its list is empty); SAC's are sac_hidden() in config.h.
std::vector<int> dqn_hidden(const config::DqnConfig& dqn);
std::vector<int> ppo_hidden(const config::PpoConfig& ppo);
// TD3's actor and critics: td3.hidden and td3.critic_hidden, or FastTD3's 512-256-128 and
// 1024-512-256 when empty.
std::vector<int> td3_hidden(const config::Td3Config& td3);
std::vector<int> td3_critic_hidden(const config::Td3Config& td3);
// FastSAC's: fastsac.hidden and fastsac.critic_hidden, or its 512-256-128 and 768-384-192 when
// empty.
std::vector<int> fastsac_hidden(const config::FastSacConfig& fastsac);
std::vector<int> fastsac_critic_hidden(const config::FastSacConfig& fastsac);

// Each algorithm's policy without parameters (params empty; PPO's log_std at its initial value and,
// where it normalizes observations, the normalizer of no data: mean 0, std 1).
PolicyParams sac_policy_shape(const config::SacConfig& sac, int obs_dim, int act_dim);
PolicyParams dqn_policy_shape(int obs_dim, int num_actions, const config::DqnConfig& dqn);
PolicyParams ppo_policy_shape(const config::PpoConfig& ppo, int obs_dim, int act_dim);
// TD3: the squashed-Gaussian head over [mean | log_std], the log_std outputs of constant weights
// (zero) and bias (log of the exploration std); with an observation normalizer where
// td3.normalize_observations.
PolicyParams td3_policy_shape(const config::Td3Config& td3, int obs_dim, int act_dim);
// FastSAC: the squashed-Gaussian head over [mean | log_std] in fastsac.activation, its log-std
// bounds, with an observation normalizer where fastsac.normalize_observations.
PolicyParams fastsac_policy_shape(const config::FastSacConfig& fastsac, int obs_dim, int act_dim);

// The shape of cfg.algorithm()'s policy for a task of this spec. Throws std::invalid_argument
// naming an algorithm it does not know.
PolicyParams policy_shape(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec);

// An untrained policy of that shape, version 0: every weight and bias uniform in
// +-1/sqrt(fan_in) (the learners' default initialization of a layer), drawn from cfg.seed().
PolicyParams untrained_policy(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec);

}  // namespace farm
