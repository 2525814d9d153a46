#include "quadruped/quadruped_spec.h"

#include "config_validator.h"

#include <cmath>
#include <string>
#include <utility>

#include "task_spec.h"

namespace farm {

namespace {

using namespace config_checks;

// A1, Honey Badger and Silver Badger (robots/quadruped). The Badger defaults the task applies to
// unset fields (kp 40, kd 1) lie in these ranges too.
void check_legged(const Section& s, const config::LeggedConfig& c) {
  s.at_least("decimation", c.decimation(), 1);
  s.check(c.physics_dt() > 0 && c.physics_dt() <= 0.05, "physics_dt",
          "expected in (0, 0.05], got " + num(c.physics_dt()));
  s.positive("kp", c.kp());
  s.non_negative("kd", c.kd());
  s.positive("action_scale", c.action_scale());
  s.positive("action_range", c.action_range());
  s.at_least("max_episode_steps", c.max_episode_steps(), 1);
  s.check(c.command_resample_prob() >= 0 && c.command_resample_prob() <= 1, "command_resample_prob",
          "expected in [0, 1], got " + num(c.command_resample_prob()));
  s.non_negative("lin_vel_x_max", c.lin_vel_x_max());
  s.non_negative("lin_vel_y_max", c.lin_vel_y_max());
  s.non_negative("ang_vel_max", c.ang_vel_max());
  s.positive("tracking_sigma", c.tracking_sigma());
  s.in_unit("soft_dof_pos_limit", c.soft_dof_pos_limit());
  s.check(c.friction_min() > 0 && c.friction_min() <= c.friction_max(), "friction_min",
          "expected 0 < friction_min <= friction_max (" + num(c.friction_max()) + "), got " + num(c.friction_min()));
  s.check(
      c.init_joint_scale_min() <= c.init_joint_scale_max(), "init_joint_scale_min",
      "expected <= init_joint_scale_max (" + num(c.init_joint_scale_max()) + "), got " + num(c.init_joint_scale_min()));
  s.check(c.push_interval_s() >= 0, "push_interval_s", "expected >= 0 (0: no pushes), got " + num(c.push_interval_s()));
  s.non_negative("noise_level", c.noise_level());
  // Relative randomization ranges +-x around the model's value: the value keeps its sign.
  for (auto [f, x] : {std::pair<const char*, double>{"trunk_mass_rel", c.trunk_mass_rel()},
                      {"torque_limit_rel", c.torque_limit_rel()},
                      {"velocity_limit_rel", c.velocity_limit_rel()},
                      {"foot_size_rel", c.foot_size_rel()},
                      {"kp_rel", c.kp_rel()},
                      {"kd_rel", c.kd_rel()},
                      {"action_scale_rel", c.action_scale_rel()},
                      {"torque_multiplier_rel", c.torque_multiplier_rel()}})
    s.check(x >= 0 && x < 1, f, "expected in [0, 1), got " + num(x));
  s.positive("velocity_limit", c.velocity_limit());
  s.check(c.armature_max() >= 0.005, "armature_max",
          "expected >= 0.005 (the lower end of its range), got " + num(c.armature_max()));
}

}  // namespace

void check_config(const config::LeggedConfig& c, const std::string& task) {
  check_in_code(c, "task." + task, check_legged);
}

namespace robots::quadruped {

namespace {

// The observation of robots/quadruped/quadruped_task.cpp: base linear and angular velocity,
// projected gravity (3 each), the command (2 + 1), joint positions, velocities and last action; the
// Badgers add the base height and the observed dynamics parameters.
constexpr int kLegs = 4, kJointsPerLeg = 3, kDynamicsParams = 16;

TaskSpec legged(const std::string& name, const config::LeggedConfig& c, bool spine, bool badger) {
  TaskSpec s;
  s.name = name;
  const int n = kLegs * kJointsPerLeg + (spine ? 1 : 0);
  s.obs_dim = 3 + 3 + 3 + 2 + 1 + 3 * n + (badger ? 1 + kDynamicsParams : 0);
  s.act_dim = n;
  s.max_episode_steps = c.max_episode_steps();
  s.metric_names = {"tracking_lin", "tracking_ang", "lin_vel_error", "fell", "time_s"};
  return s;
}

}  // namespace

TaskSpec a1_spec(const config::TaskConfig& cfg) { return legged("a1", cfg.a1(), false, false); }
TaskSpec honey_badger_spec(const config::TaskConfig& cfg) {
  return legged("honey_badger", cfg.honey_badger(), false, true);
}
TaskSpec silver_badger_spec(const config::TaskConfig& cfg) {
  return legged("silver_badger", cfg.silver_badger(), true, true);
}

void check_a1(const config_checks::Section& task, const config::TaskConfig& t) {
  check_legged(task.nest("a1", t.a1()), t.a1());
}
void check_honey_badger(const config_checks::Section& task, const config::TaskConfig& t) {
  check_legged(task.nest("honey_badger", t.honey_badger()), t.honey_badger());
}
void check_silver_badger(const config_checks::Section& task, const config::TaskConfig& t) {
  check_legged(task.nest("silver_badger", t.silver_badger()), t.silver_badger());
}

}  // namespace robots::quadruped

}  // namespace farm
