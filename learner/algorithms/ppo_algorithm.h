// PPO in the learner: tells the workers how much to produce for each policy version (a quota of
// batches per worker), gates batches by the version that made them, fits when the fit scheduler
// says so, evaluates every few fits and writes one log line and CSV row per fit.
#pragma once

#include <memory>

#include "algorithm.h"
#include "farm_config.pb.h"
#include "task_spec.h"

namespace farm {

// Throws std::invalid_argument when the task has discrete actions or the ppo section is unusable.
std::unique_ptr<Algorithm> make_ppo(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec);

}  // namespace farm
