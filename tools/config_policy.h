// A policy for a config file's experiment when no manifest names it: the policy file of a policy
// folder shipped without a manifest (e.g. docs/data/mclari_terrain_policy), or, with no folder, an
// untrained policy of the experiment's algorithm (common/policy_shape.h). No LibTorch: a folder
// that holds only an algorithm's networks gets its policy file from farm-policy-file --config.
#pragma once

#include <string>

#include "run_policy.h"

namespace farm::tools {

// The experiment of a config file with the policy file DIR/policy.bin or, with an empty DIR, its
// untrained policy (the config's seed), to look at a task before training. The policy's version
// and updates are the file's version (farm-policy-file --config writes the networks' update count
// there). Throws std::runtime_error naming what is missing or wrong (no such folder, an unknown
// task or algorithm, no policy file and how to write it, a policy that does not fit the task or is
// not of the config's algorithm).
RunPolicy config_policy(const std::string& config_path, const std::string& dir);

}  // namespace farm::tools
