#include "pendulum/pendulum_spec.h"

#include "config_validator.h"

#include <algorithm>
#include <cmath>
#include <string>
#include <utility>

#include "task_spec.h"

namespace farm {

namespace {

using namespace config_checks;

void check_pendulum(const Section& s, const config::PendulumConfig& p) {
  for (auto [f, x] : {std::pair<const char*, double>{"gravity", p.gravity()},
                      {"mass", p.mass()},
                      {"length", p.length()},
                      {"dt", p.dt()},
                      {"max_speed", p.max_speed()},
                      {"max_torque", p.max_torque()}})
    s.finite_positive(f, x);
  s.finite_non_negative("velocity_cost", p.velocity_cost());
  s.finite_non_negative("torque_cost", p.torque_cost());
  s.finite_non_negative("init_max_speed", p.init_max_speed());
  s.positive("max_episode_steps", p.max_episode_steps());
}

}  // namespace

void check_config(const config::PendulumConfig& c) { check_in_code(c, "task.pendulum", check_pendulum); }

namespace robots::pendulum {

TaskSpec pendulum_spec(const config::TaskConfig& cfg) {
  TaskSpec s;
  s.name = "pendulum";
  s.obs_dim = 3;  // cos theta, sin theta, theta dot
  s.act_dim = 1;
  s.max_episode_steps = cfg.pendulum().max_episode_steps();
  s.metric_names = {"upright_fraction"};
  // Pendulum-v1's cost at its largest: the angle at pi, the speed at its clip (or the reset's
  // range), the torque at its limit.
  const auto& p = cfg.pendulum();
  const double v = std::max(p.max_speed(), p.init_max_speed());
  s.reward_bound =
      M_PI * M_PI + std::abs(p.velocity_cost()) * v * v + std::abs(p.torque_cost()) * p.max_torque() * p.max_torque();
  // A cost (the config's costs are never negative): the reward is never positive.
  s.reward_max = 0;
  return s;
}

void check_pendulum(const config_checks::Section& task, const config::TaskConfig& t) {
  farm::check_pendulum(task.nest("pendulum", t.pendulum()), t.pendulum());
}

}  // namespace robots::pendulum

}  // namespace farm
