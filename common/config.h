// Experiment configuration: Protobuf text format checked against the schema in
// farm_config.proto, then against the ranges each field needs. Every error names the file, the
// line and the field.
#pragma once

#include <functional>
#include <stdexcept>
#include <string>
#include <vector>

#include "farm_config.pb.h"

namespace farm {

// Sizes a worker takes, from its flags, its config or a spec off the bus: they bound what one
// worker's environments and one batch hold in memory.
inline constexpr int kMaxEnvsPerWorker = 4096;
// Episodes of one evaluation (each runs in an env of its own on the worker asked).
inline constexpr int kMaxEvalEpisodes = 16384;
inline constexpr int kMaxThreadsPerWorker = 256;
inline constexpr int kMaxStepsPerBatch = 4096;
inline constexpr long long kMaxBatchTransitions = 1 << 20;  // steps x envs of one batch

struct ConfigError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

namespace config_checks {
class Section;
}

// What the checks need to know of the tasks, which common/ does not: the robots' registry gives it
// (robots::task_knowledge(), robots/task_specs.h, with loaders that pass it). Each is called where
// the checks of the task belong, so that its errors name the file, the line and the field as every
// other check does.
struct TaskKnowledge {
  // Reads into the task's section the files it names relative to `folder` (a config file's folder:
  // a task of terms' model); fails through `task`, the section "task".
  std::function<void(config::TaskConfig* cfg, const std::string& folder, const config_checks::Section& task)>
      read_files;
  // The range checks of the section of the task that runs (task.<name>).
  std::function<void(const config_checks::Section& task, const config::TaskConfig& cfg)> check_section;
  // The task's metric names (eval.best_metric and stop.eval_goal name one); throws
  // std::invalid_argument for a task it does not know.
  std::function<std::vector<std::string>(const config::TaskConfig& cfg)> metric_names;
};

// Throws ConfigError ("FILE:LINE:COL: field 'sac.batch_size': expected > 0, got -3"). Every range
// a task or an algorithm needs of its section is checked here; only the section of the task that
// runs (task.name) is checked, and the dqn, ppo, td3 and fastsac sections only when the algorithm is
// theirs.
config::ExperimentConfig load_config_file(const std::string& path, const TaskKnowledge& tasks);
// The ExperimentConfig fields marked as algorithm sections (farm_options.proto), in schema order:
// the names `algorithm` may take.
std::vector<std::string> algorithm_sections();
// load_config_file's checks on the text of a config file in `folder` ("" for a text of no folder,
// whose model paths are not read): the files a task names (task.terms.model, relative to that
// folder) are read into the config.
config::ExperimentConfig parse_config_text(const std::string& text, const std::string& source,
                                           const std::string& folder, const TaskKnowledge& tasks);

// Fields that name a file the process building the task writes (marked output_path in the schema):
// the set ones, by path ("task.<section>.<field>"), and a way to clear them all.
std::vector<std::string> output_path_fields(const config::ExperimentConfig& cfg);
void clear_output_paths(config::ExperimentConfig* cfg);
// parse_config_text for a config that came over the bus (a worker's ExperimentSpec): it may not
// name a file for the receiving host to write; ConfigError names the field.
config::ExperimentConfig parse_config_from_bus(const std::string& text, const std::string& source,
                                               const TaskKnowledge& tasks);

// What a run resumed with config `now` from a checkpoint written with config `was` may not change:
// the algorithm, and for SAC, DQN and TD3 the gamma its replay rows were summed with where they sum
// several rewards (n_step > 1: resumed with another gamma, they would mix two). "" when none changed.
std::string resume_change(const config::ExperimentConfig& was, const config::ExperimentConfig& now);

// The experiment config as text (what the learner sends to the workers in the ExperimentSpec).
std::string config_to_text(const config::ExperimentConfig& cfg);

// "cpu", "cuda", "cuda:N" (N a device index) or "auto" (the first GPU where the learner's LibTorch
// sees one, else the CPU): the learner devices a config may name.
bool valid_device_name(const std::string& name);

// The loader's range checks of one algorithm section, for a config that did not come through the
// loader (unit tests, tools that change a loaded config). The error names the field path, as there
// is no file: std::invalid_argument("field 'sac.batch_size': expected > 0, got 0"). A task
// section's own check_config is in its robot's folder (robots/<robot>/<robot>_spec.h).
void check_config(const config::SacConfig& c);
void check_config(const config::DqnConfig& c);
void check_config(const config::PpoConfig& c);
void check_config(const config::Td3Config& c);
void check_config(const config::FastSacConfig& c);

// Hidden sizes of the SAC networks (the schema's default when the list is empty).
std::vector<int> sac_hidden(const config::SacConfig& sac);
// The critics' hidden sizes: sac.critic_hidden, or sac_hidden() when it is empty.
std::vector<int> sac_critic_hidden(const config::SacConfig& sac);

}  // namespace farm
