// The registered tasks (robots/tasks.def) as the MuJoCo-free side sees them: each task's spec from
// its config (task_spec(), declared in common/task_spec.h) and the loader's range checks of its
// config section.
#pragma once

#include <string>
#include <vector>

#include "config_validator.h"
#include "farm_config.pb.h"
#include "task_spec.h"

namespace farm::robots {

// The checks of the section of the task that runs (task.<name>); the other sections are never
// read. A name no task registers is left to the task registry (robots/task.cpp), which names the
// known tasks.
void check_task_section(const config_checks::Section& task, const config::TaskConfig& cfg);

// The registered names, in tasks.def's order.
std::vector<std::string> registered_task_names();

}  // namespace farm::robots
