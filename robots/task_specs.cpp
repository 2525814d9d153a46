#include "task_specs.h"

#include <stdexcept>

namespace farm::robots {

#define TASK(name, family, make, spec, check)                                    \
  namespace family {                                                             \
  TaskSpec spec(const config::TaskConfig& cfg);                                  \
  void check(const config_checks::Section& task, const config::TaskConfig& cfg); \
  }
#include "tasks.def"
#undef TASK

namespace {

struct SpecEntry {
  const char* name;
  TaskSpec (*spec)(const config::TaskConfig&);
  void (*check)(const config_checks::Section&, const config::TaskConfig&);
};

const SpecEntry kSpecs[] = {
#define TASK(name, family, make, spec, check) {#name, &family::spec, &family::check},
#include "tasks.def"
#undef TASK
};

}  // namespace

TaskSpec task_spec(const config::TaskConfig& cfg) {
  for (const auto& e : kSpecs)
    if (cfg.name() == e.name) return e.spec(cfg);
  throw std::invalid_argument("no task spec for task '" + cfg.name() + "'");
}

void check_task_section(const config_checks::Section& task, const config::TaskConfig& cfg) {
  for (const auto& e : kSpecs)
    if (cfg.name() == e.name) e.check(task, cfg);
}

std::vector<std::string> registered_task_names() {
  std::vector<std::string> names;
  for (const auto& e : kSpecs) names.emplace_back(e.name);
  return names;
}

}  // namespace farm::robots
