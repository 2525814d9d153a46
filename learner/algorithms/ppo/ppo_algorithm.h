// PPO in the learner (ppo_algorithm.cpp): the networks, their rollout storage and fit scheduler.
#pragma once

#include <memory>
#include <string>

#include "algorithm.h"
#include "farm_config.pb.h"
#include "task_spec.h"

namespace farm {

// A GPU loads a kernel the first time a fit uses it; on a freshly started machine (libraries not
// yet read from disk) that made the A1's second fit come 8.8 s after the first instead of 2.4 s,
// while an asynchronous run's workers simulated on and their steps went stale. This fits a
// throwaway copy of the networks (pc, on `device`) once on synthetic steps of one fit's shapes,
// made by versions up to max_policy_lag behind the fitted one so that the off-policy correction
// runs too, and leaves LibTorch's CPU generator as it found it. Returns the seconds it took.
double ppo_warm_up(const config::PpoConfig& pc, int obs_dim, int act_dim, uint64_t seed, const std::string& device);

// Throws std::invalid_argument when the task has discrete actions or the ppo section is unusable.
std::unique_ptr<Algorithm> make_ppo(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec);

}  // namespace farm
