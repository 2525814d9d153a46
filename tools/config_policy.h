// A policy from a config file and networks without a policy file: a policy folder shipped as the
// learner's networks only (e.g. docs/data/mclari_terrain_policy), or the untrained policy the
// config's learner starts from. It reads the networks with the learner's algorithms (LibTorch);
// a checkpoint's policy file needs none (run_policy.h).
#pragma once

#include <string>

#include "run_policy.h"

namespace farm::tools {

// The experiment of a config file with the networks in DIR or, with an empty DIR, its untrained
// policy (the networks its learner starts from, the config's seed), to look at a task before
// training. Throws std::runtime_error naming what is missing or wrong (no such folder, an unknown
// task or algorithm, missing networks, networks that do not fit the task).
RunPolicy config_policy(const std::string& config_path, const std::string& dir);

}  // namespace farm::tools
