#include "mobile/mobile_spec.h"

#include "config_validator.h"

#include <cmath>
#include <string>
#include <utility>

#include "task_spec.h"

namespace farm {

namespace {

using namespace config_checks;

// The arena and its obstacle map (robots/mobile/obstacle_map.h). Whether the robot fits the arena
// depends on its model too: MapGenerator checks that.
void check_scene(const Section& s, const config::MobileSceneConfig& c) {
  s.check(c.lidar_rays() >= 1 && c.lidar_rays() <= 1024, "lidar_rays",
          "expected in [1, 1024], got " + num(c.lidar_rays()));
  s.positive("lidar_range", c.lidar_range());
  s.check(c.lidar_fov_deg() > 0 && c.lidar_fov_deg() <= 360, "lidar_fov_deg",
          "expected in (0, 360], got " + num(c.lidar_fov_deg()));
  s.positive("arena_half_size", c.arena_half_size());
  s.positive("wall_height", c.wall_height());
  s.non_negative("min_obstacles", c.min_obstacles());
  s.check(c.max_obstacles() >= c.min_obstacles(), "max_obstacles",
          "expected >= min_obstacles (" + num(c.min_obstacles()) + "), got " + num(c.max_obstacles()));
  // One MuJoCo body per obstacle slot.
  s.check(c.max_obstacles() <= 256, "max_obstacles", "expected <= 256, got " + num(c.max_obstacles()));
  s.positive("obstacle_min_half_size", c.obstacle_min_half_size());
  s.check(c.obstacle_max_half_size() >= c.obstacle_min_half_size(), "obstacle_max_half_size",
          "expected >= obstacle_min_half_size (" + num(c.obstacle_min_half_size()) + "), got " +
              num(c.obstacle_max_half_size()));
  s.check(c.obstacle_max_half_size() < c.arena_half_size(), "obstacle_max_half_size",
          "expected < arena_half_size (" + num(c.arena_half_size()) + "), got " + num(c.obstacle_max_half_size()));
  s.non_negative("clearance", c.clearance());
  s.non_negative("min_start_goal_distance", c.min_start_goal_distance());
  s.positive("goal_radius", c.goal_radius());
  s.positive("max_episode_steps", c.max_episode_steps());
  s.check(c.physics_dt() > 0 && c.physics_dt() <= 0.05, "physics_dt",
          "expected in (0, 0.05], got " + num(c.physics_dt()));
  s.at_least("control_substeps", c.control_substeps(), 1);
  s.non_negative("distance_weight", c.distance_weight());
  s.check(c.collision_penalty() >= 0, "collision_penalty",
          "expected >= 0 (it is subtracted), got " + num(c.collision_penalty()));
  s.at_least("max_reset_tries", c.max_reset_tries(), 1);
}

// JetbotConfig and KayaConfig: the same fields around the same scene.
template <typename Robot>
void check_mobile(const Section& s, const Robot& r) {
  s.finite_positive("max_linear_speed", r.max_linear_speed());
  s.finite_positive("max_angular_speed", r.max_angular_speed());
  s.finite_positive("wheel_kv", r.wheel_kv());
  s.finite_positive("wheel_max_torque", r.wheel_max_torque());
  check_scene(s.nest("scene", r.scene()), r.scene());
}

}  // namespace

void check_config(const config::JetbotConfig& c) {
  check_in_code(c, "task.jetbot", check_mobile<config::JetbotConfig>);
}
void check_config(const config::KayaConfig& c) { check_in_code(c, "task.kaya", check_mobile<config::KayaConfig>); }

namespace robots::mobile {

namespace {

// Lidar rays, goal (3), wheel speeds, base velocity (3); discrete commands: 7 for the differential
// base, 8 directions and 2 turns for the holonomic one.
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

}  // namespace

TaskSpec jetbot_spec(const config::TaskConfig& cfg) { return mobile("jetbot", cfg.jetbot().scene(), true); }
TaskSpec kaya_spec(const config::TaskConfig& cfg) { return mobile("kaya", cfg.kaya().scene(), false); }

void check_jetbot(const config_checks::Section& task, const config::TaskConfig& t) {
  check_mobile(task.nest("jetbot", t.jetbot()), t.jetbot());
}
void check_kaya(const config_checks::Section& task, const config::TaskConfig& t) {
  check_mobile(task.nest("kaya", t.kaya()), t.kaya());
}

}  // namespace robots::mobile

}  // namespace farm
