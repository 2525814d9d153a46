// The learner service for off-policy SAC and DQN: keeps the workers' transitions in a replay
// buffer, updates as fast as the data and the algorithm's pacing allow, publishes the policy every
// few updates, evaluates on a timer, checkpoints the networks with the buffer and resumes.
#pragma once

#include <atomic>

#include "farm_config.pb.h"
#include "learner_service.h"

namespace farm {

// Runs the experiment to its end; returns the process exit code (130 when interrupted).
int run_off_policy_learner(const LearnerRunOptions& opt, const config::ExperimentConfig& cfg,
                           const std::atomic<bool>& interrupted);

}  // namespace farm
