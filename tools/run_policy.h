// A trained run's policy as the workers run it, read from a checkpoint folder (RUN/checkpoint or
// RUN/best): the manifest's experiment config, the task it names, and the policy file the learner
// wrote there (policy.bin, common/policy_file.h: the networks of whichever algorithm trained it,
// with the observation normalizer), without LibTorch. The one loader of the programs that read a
// run's policy (farm-play, farm-export, farm-mobile-eval); config_policy.h reads a policy file that
// has no manifest beside it, or makes an untrained policy.
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
  // The experiment, its output paths cleared (building its task writes no file).
  config::ExperimentConfig config;
  config::CheckpointManifest manifest;  // empty for config_policy
  std::shared_ptr<robots::Task> task;
  PolicyParams policy;  // version: the manifest's policy_version (0 for config_policy)
  int64_t updates = 0;  // the training updates of the networks read (0 untrained)
};

// Reads DIR/manifest.txtpb and the policy file DIR/policy.bin. Throws std::runtime_error naming
// what is missing or wrong (no such folder, a run folder passed where its checkpoint was meant, no
// manifest, one that does not parse (with its line and column) or is far bigger than any manifest,
// an unknown task, no policy file (a checkpoint of a learner that wrote none: how to write it), a
// policy file that is not one or does not fit the task).
RunPolicy load_run_policy(const std::string& dir);

// Throws std::runtime_error naming `file` unless policy p fits the task: its observations in, and
// the outputs its head needs for the task's actions.
void check_fits(const PolicyParams& p, const robots::TaskSpec& spec, const std::string& file);

// The config's task, built without writing any file its config names; no policy yet.
RunPolicy with_task(config::ExperimentConfig cfg);

// RUN/best with best = true, else RUN/checkpoint, when it holds a manifest. Otherwise throws naming
// the missing manifest and what the run holds instead: a checkpoint (leave out --best), the
// checkpoint.old a learner stopped while saving left, or nothing a learner writes.
std::string run_policy_dir(const std::string& run, bool best);

}  // namespace farm::tools
