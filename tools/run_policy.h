// A trained run's policy as the workers run it, read from a checkpoint folder (RUN/checkpoint or
// RUN/best): the manifest's experiment config, the task it names, and the networks of whichever
// algorithm trained it (SAC, DQN, PPO) exported with the observation normalizer.
#pragma once

#include <memory>
#include <string>

#include "farm_config.pb.h"
#include "mlp.h"
#include "task.h"

namespace farm::tools {

struct RunPolicy {
  std::string dir;  // the checkpoint folder read
  config::ExperimentConfig config;
  config::CheckpointManifest manifest;
  std::shared_ptr<robots::Task> task;
  PolicyParams policy;  // version: the manifest's policy_version
};

// Reads DIR/manifest.txtpb and the algorithm's networks in DIR. Throws std::runtime_error naming
// what is missing or wrong (no such folder, a run folder passed where its checkpoint was meant, no
// manifest, an unknown task or algorithm, networks that do not fit the task).
RunPolicy load_run_policy(const std::string& dir);

// The experiment of a config file with the networks in DIR (a policy folder shipped without a
// manifest, e.g. docs/data/mclari_terrain_policy) or, with an empty DIR, its untrained policy (the
// networks its learner starts from, the config's seed), to look at a task before training. Throws as
// load_run_policy does.
RunPolicy config_policy(const std::string& config_path, const std::string& dir);

// RUN/best with best = true, else RUN/checkpoint; a missing one is named with what the run holds.
std::string run_policy_dir(const std::string& run, bool best);

}  // namespace farm::tools
