// PPO's networks read back as the workers' policy (ppo_policy.h).
#include "ppo_policy.h"

#include "ppo.h"

namespace farm {

PolicyParams read_ppo_policy(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec, const std::string& dir,
                             uint64_t version, int64_t* updates) {
  Ppo ppo(cfg.ppo(), spec.obs_dim, spec.act_dim, cfg.seed());
  if (!dir.empty()) ppo.load(dir);
  *updates = ppo.updates();
  return ppo.export_policy(version);
}

}  // namespace farm
