// A trained run's policy as the workers run it, read from a checkpoint folder (RUN/checkpoint or
// RUN/best): the manifest's experiment config, the task it names, and the networks of whichever
// algorithm trained it (SAC, DQN, PPO) exported with the observation normalizer. The one loader of
// the programs that read a run's policy (farm-play, farm-export, farm-mobile-eval).
#pragma once

#include <cstdint>
#include <memory>
#include <string>

#include "farm_config.pb.h"
#include "mlp.h"
#include "task.h"

namespace farm::tools {

struct RunPolicy {
  std::string dir;  // the checkpoint folder read ("" for an untrained policy)
  // The experiment, its output paths cleared (building its task writes no file); the networks
  // were built from a copy that loads them on the CPU whatever device they trained on.
  config::ExperimentConfig config;
  config::CheckpointManifest manifest;  // empty for config_policy
  std::shared_ptr<robots::Task> task;
  PolicyParams policy;  // version: the manifest's policy_version (0 for config_policy)
  int64_t updates = 0;  // the training updates of the networks read (0 untrained)
};

// Reads DIR/manifest.txtpb and the algorithm's networks in DIR/<algorithm>/<algorithm>.pt. Throws
// std::runtime_error naming what is missing or wrong (no such folder, a run folder passed where its
// checkpoint was meant, no manifest, one that does not parse (with its line and column) or is far
// bigger than any manifest, an unknown task or algorithm, missing networks, networks that do not
// fit the task).
RunPolicy load_run_policy(const std::string& dir);

// The experiment of a config file with the networks in DIR (a policy folder shipped without a
// manifest, e.g. docs/data/mclari_terrain_policy) or, with an empty DIR, its untrained policy (the
// networks its learner starts from, the config's seed), to look at a task before training. Throws as
// load_run_policy does.
RunPolicy config_policy(const std::string& config_path, const std::string& dir);

// RUN/best with best = true, else RUN/checkpoint, when it holds a manifest. Otherwise throws naming
// the missing manifest and what the run holds instead: a checkpoint (leave out --best), the
// checkpoint.old a learner stopped while saving left, or nothing a learner writes.
std::string run_policy_dir(const std::string& run, bool best);

}  // namespace farm::tools
