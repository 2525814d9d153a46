// PPO's policy for the programs that read a trained run (tools/run_policy.cpp, through the
// registry's read_policy): its learner side (ppo_algorithm.cpp) exports no policy of its own, so
// the networks are read by Ppo itself.
#pragma once

#include <cstdint>
#include <string>

#include "farm_config.pb.h"
#include "mlp.h"
#include "task_spec.h"

namespace farm {

// The policy of the networks PPO saved in `dir` (its checkpoint sub-folder), or as it starts when
// `dir` is empty, with their update count in *updates. Throws what Ppo::load throws.
PolicyParams read_ppo_policy(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec, const std::string& dir,
                             uint64_t version, int64_t* updates);

}  // namespace farm
