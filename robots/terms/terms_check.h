// The loader's checks of task.terms (the task registry, robots/task_specs.cpp, gives them to
// common/config.cpp's checks for a task named "terms").
#pragma once

#include "farm_config.pb.h"

namespace farm::config_checks {
class Section;
}

namespace farm::robots::terms {

// Every range, term name, term parameter and model name of the section; the model bundle too
// (model_files filled). Fails through the Section: FILE:LINE:COL and the field's path.
void check_terms(const config_checks::Section& s, const config::TermsConfig& c);
// The same for the task section `task` (robots/tasks.def): its "terms" section.
void check_terms(const config_checks::Section& task, const config::TaskConfig& t);

}  // namespace farm::robots::terms
