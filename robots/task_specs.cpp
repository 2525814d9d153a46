#include "task_specs.h"

#include <stdexcept>
#include <type_traits>
#include <utility>

#include "config_validator.h"
#include "terms/mjcf_bundle.h"

namespace farm::robots {

#define TASK(name, family, make, spec, check, section, number)                   \
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

// Each task's config section is the field of TaskConfig its registration line makes (the build
// writes TaskConfig from tasks.def), of the message the line names.
#define TASK(name, family, make, spec, check, section, number)                                                      \
  static_assert(std::is_same_v<std::decay_t<decltype(std::declval<config::TaskConfig>().name())>, config::section>, \
                "task." #name " is not a " #section);
#include "tasks.def"
#undef TASK

const SpecEntry kSpecs[] = {
#define TASK(name, family, make, spec, check, section, number) {#name, &family::spec, &family::check},
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

namespace {

// A task of terms names its model by a path relative to the config's folder (or an absolute one):
// the model's files are read into task.terms.model_files, unless they came with the config.
void read_task_files(config::TaskConfig* cfg, const std::string& folder, const config_checks::Section& task) {
  const auto& given = cfg->terms();
  if (cfg->name() != "terms" || given.model_files_size() > 0 || given.model().empty()) return;
  config::TermsConfig* section = cfg->mutable_terms();
  const config_checks::Section t = task.nest("terms", cfg->terms());
  try {
    const std::string& model = section->model();
    terms::read_model_folder(model[0] == '/' ? model : folder + "/" + model, section);
  } catch (const terms::ModelError& e) {
    t.fail("model", e.what());
  }
}

}  // namespace

const TaskKnowledge& task_knowledge() {
  static const TaskKnowledge k{&read_task_files, &check_task_section,
                               [](const config::TaskConfig& cfg) { return task_spec(cfg).metric_names; }};
  return k;
}

config::ExperimentConfig load_config_file(const std::string& path) {
  return farm::load_config_file(path, task_knowledge());
}

config::ExperimentConfig parse_config_text(const std::string& text, const std::string& source,
                                           const std::string& folder) {
  return farm::parse_config_text(text, source, folder, task_knowledge());
}

config::ExperimentConfig parse_config_from_bus(const std::string& text, const std::string& source) {
  return farm::parse_config_from_bus(text, source, task_knowledge());
}

}  // namespace farm::robots
