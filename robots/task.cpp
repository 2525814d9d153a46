#include "task.h"

#include <mujoco/mujoco.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>

namespace farm::robots {

// Each registered task's make function, declared from its line of robots/tasks.def.
#define TASK(name, family, make, spec, check, section, number) \
  namespace family {                                           \
  std::unique_ptr<Task> make(const config::TaskConfig& cfg);   \
  }
#include "tasks.def"
#undef TASK

TaskState::~TaskState() {
  if (data) mj_deleteData(data);
}

Task::~Task() = default;

void Task::episode_metrics(const TaskState&, float*) const {}

void Task::view(const TaskState&, const mjData*, int, TaskView&) const {}

void mix_pair_friction(mjModel* m, int p) {
  const mjtNum* f1 = m->geom_friction + 3 * m->pair_geom1[p];
  const mjtNum* f2 = m->geom_friction + 3 * m->pair_geom2[p];
  mjtNum* f = m->pair_friction + 5 * p;
  f[0] = f[1] = std::max(f1[0], f2[0]);
  f[2] = std::max(f1[1], f2[1]);
  f[3] = f[4] = std::max(f1[2], f2[2]);
}

void command_view(const double command[3], const mjData* pose, int root, TaskView& out) {
  const mjtNum* x = pose->xmat + 9 * root;
  const double yaw = std::atan2(x[3], x[0]);
  const double vx = command[0] * std::cos(yaw) - command[1] * std::sin(yaw);
  const double vy = command[0] * std::sin(yaw) + command[1] * std::cos(yaw);
  if (std::hypot(vx, vy) > 1e-3) {
    ViewMarker arrow;
    arrow.kind = ViewMarker::kArrow;
    const mjtNum* p = pose->xpos + 3 * root;
    for (int k = 0; k < 3; ++k) arrow.pos[k] = arrow.to[k] = p[k];
    arrow.pos[2] = arrow.to[2] = p[2] + 0.15;
    arrow.to[0] += vx;
    arrow.to[1] += vy;
    arrow.radius = 0.02;
    const float green[4] = {0.1f, 0.8f, 0.2f, 0.9f};
    std::copy(green, green + 4, arrow.rgba);
    out.markers.push_back(arrow);
  }
  char text[128];
  std::snprintf(text, sizeof text, "vx %+.2f vy %+.2f yaw %+.2f", command[0], command[1], command[2]);
  out.rows.push_back({"command", text});
}

namespace {

struct Registration {
  const char* name;
  std::unique_ptr<Task> (*make)(const config::TaskConfig&);
};

// robots/tasks.def: one line per task.
const Registration kTasks[] = {
#define TASK(name, family, make, spec, check, section, number) {#name, &family::make},
#include "tasks.def"
#undef TASK
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
