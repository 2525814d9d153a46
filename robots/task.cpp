#include "task.h"

#include <mujoco/mujoco.h>

#include <stdexcept>

#include "cartpole/cartpole_task.h"
#include "mclari/mclari_task.h"
#include "mobile/mobile_task.h"
#include "pendulum/pendulum_task.h"
#include "quadruped/quadruped_task.h"
#include "terms/terms_task.h"

namespace farm::robots {

TaskState::~TaskState() {
  if (data) mj_deleteData(data);
}

Task::~Task() = default;

void Task::episode_metrics(const TaskState&, float*) const {}

namespace {

struct Registration {
  const char* name;
  std::unique_ptr<Task> (*make)(const config::TaskConfig&);
};

// One line per task.
const Registration kTasks[] = {
    {"pendulum", &make_pendulum_task},
    {"cartpole", &make_cartpole_task},
    {"jetbot", &mobile::make_jetbot_task},
    {"kaya", &mobile::make_kaya_task},
    {"mclari", &make_mclari_task},
    {"a1", &quadruped::make_a1_task},
    {"honey_badger", &quadruped::make_honey_badger_task},
    {"silver_badger", &quadruped::make_silver_badger_task},
    {"terms", &terms::make_terms_task},
};

}  // namespace

std::unique_ptr<Task> make_task(const config::TaskConfig& cfg) {
  for (const auto& t : kTasks) {
    if (cfg.name() == t.name) return t.make(cfg);
  }
  std::string known;
  for (const auto& n : task_names()) known += (known.empty() ? "" : ", ") + n;
  throw std::invalid_argument("unknown task '" + cfg.name() + "'; known tasks: " + known);
}

std::vector<std::string> task_names() {
  std::vector<std::string> names;
  for (const auto& t : kTasks) names.emplace_back(t.name);
  return names;
}

}  // namespace farm::robots
