// The registered tasks (robots/tasks.def) as the MuJoCo-free side sees them: each task's spec from
// its config, the loader's range checks of its config section, and the config loader
// (common/config.h) given what the tasks know.
#pragma once

#include <string>
#include <vector>

#include "config.h"
#include "farm_config.pb.h"
#include "task_spec.h"

namespace farm::robots {

// The spec of the task cfg names, from the config alone (no MuJoCo), as its robot's folder defines
// it: what robots::make_task(cfg) builds reports the same spec()
// (tests/unit/test_task_conformance.cpp). Throws std::invalid_argument for a task it does not know.
TaskSpec task_spec(const config::TaskConfig& cfg);

// The checks of the section of the task that runs (task.<name>); the other sections are never
// read. A name no task registers is left to the task registry (robots/task.cpp), which names the
// known tasks.
void check_task_section(const config_checks::Section& task, const config::TaskConfig& cfg);

// The registered names, in tasks.def's order.
std::vector<std::string> registered_task_names();

// What the config checks take of the registered tasks: their section checks, their metric names,
// and a task of terms' model files read from the config's folder.
const TaskKnowledge& task_knowledge();

// The loaders of common/config.h with task_knowledge(): what every program reads a config with.
config::ExperimentConfig load_config_file(const std::string& path);
config::ExperimentConfig parse_config_text(const std::string& text, const std::string& source,
                                           const std::string& folder = "");
config::ExperimentConfig parse_config_from_bus(const std::string& text, const std::string& source);

}  // namespace farm::robots
