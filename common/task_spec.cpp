// Every task's TaskSpec from its config alone, without building the task: the learner, which
// never steps a simulation and links no MuJoCo, sizes its networks and its checks of the workers'
// data from it. tests/unit/test_task_conformance.cpp holds each registered task's spec() to it.
#include "task_spec.h"

#include <stdexcept>

#include "terms/terms_spec.h"

namespace farm::robots {

namespace {

// The legged robots' observation (robots/quadruped/quadruped_task.cpp): base linear and angular
// velocity, projected gravity (3 each), the command (2 + 1), joint positions, velocities and last
// action; the Badgers add the base height and the observed dynamics parameters.
constexpr int kLeggedLegs = 4, kLeggedJointsPerLeg = 3, kLeggedDynamicsParams = 16;

TaskSpec legged(const std::string& name, const config::LeggedConfig& c, bool spine, bool badger) {
  TaskSpec s;
  s.name = name;
  const int n = kLeggedLegs * kLeggedJointsPerLeg + (spine ? 1 : 0);
  s.obs_dim = 3 + 3 + 3 + 2 + 1 + 3 * n + (badger ? 1 + kLeggedDynamicsParams : 0);
  s.act_dim = n;
  s.max_episode_steps = c.max_episode_steps();
  s.metric_names = {"tracking_lin", "tracking_ang", "lin_vel_error", "fell", "time_s"};
  return s;
}

// The mobile robots (robots/mobile/mobile_task.cpp): lidar rays, goal (3), wheel speeds, base
// velocity (3); discrete commands: 7 for the differential base, 8 directions and 2 turns for the
// holonomic one.
TaskSpec mobile(const std::string& name, const config::MobileSceneConfig& c, bool differential) {
  TaskSpec s;
  s.name = name;
  const int wheels = differential ? 2 : 3;
  s.obs_dim = c.lidar_rays() + 3 + wheels + 3;
  s.num_actions = c.discrete_actions() ? (differential ? 7 : 10) : 0;
  s.act_dim = c.discrete_actions() ? 1 : (differential ? 2 : 3);
  s.max_episode_steps = c.max_episode_steps();
  s.metric_names = {"success", "time_s", "path_m", "collision", "final_distance"};
  return s;
}

TaskSpec simple(const std::string& name, int obs_dim, int act_dim, int max_steps, std::vector<std::string> metrics) {
  TaskSpec s;
  s.name = name;
  s.obs_dim = obs_dim;
  s.act_dim = act_dim;
  s.max_episode_steps = max_steps;
  s.metric_names = std::move(metrics);
  return s;
}

}  // namespace

TaskSpec task_spec(const config::TaskConfig& cfg) {
  const std::string& n = cfg.name();
  if (n == "pendulum") return simple(n, 3, 1, cfg.pendulum().max_episode_steps(), {"upright_fraction"});
  if (n == "cartpole") return simple(n, 5, 1, cfg.cartpole().max_episode_steps(), {"upright_fraction"});
  if (n == "mclari") {
    const auto& m = cfg.mclari();
    return simple(n, 4 + (m.observe_gait() ? 2 : 0) + (m.observe_terrain() ? 3 : 0), 2, m.max_episode_steps(),
                  {"efficiency", "fell", "reached", "terrain", "mean_frequency", "final_distance", "share"});
  }
  if (n == "jetbot") return mobile(n, cfg.jetbot().scene(), true);
  if (n == "kaya") return mobile(n, cfg.kaya().scene(), false);
  if (n == "a1") return legged(n, cfg.a1(), false, false);
  if (n == "honey_badger") return legged(n, cfg.honey_badger(), false, true);
  if (n == "silver_badger") return legged(n, cfg.silver_badger(), true, true);
  if (n == "terms") return terms::task_spec(cfg.terms());
  throw std::invalid_argument("no task spec for task '" + n + "'");
}

}  // namespace farm::robots
