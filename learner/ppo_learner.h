// The learner service for on-policy PPO: publishes the experiment, tells the workers how much to
// produce for each policy version, gates batches by the version that made them, fits when the
// fit scheduler says so, evaluates, logs one line per fit, checkpoints and resumes.
#pragma once

#include <atomic>

#include "farm_config.pb.h"
#include "learner_service.h"

namespace farm {

// Runs the experiment to its end; returns the process exit code (130 when interrupted).
int run_ppo_learner(const LearnerRunOptions& opt, const config::ExperimentConfig& cfg,
                    const std::atomic<bool>& interrupted);

}  // namespace farm
