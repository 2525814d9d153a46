#include "cartpole/cartpole_spec.h"

#include "config_validator.h"

#include <cmath>
#include <string>
#include <utility>

#include "task_spec.h"

namespace farm {

namespace {

using namespace config_checks;

void check_cartpole(const Section& s, const config::CartpoleConfig& c) {
  s.finite_positive("physics_dt", c.physics_dt());
  s.finite_positive("max_force", c.max_force());
  s.finite_positive("gear", c.gear());
  s.finite_positive("rail_limit", c.rail_limit());
  s.positive("control_substeps", c.control_substeps());
  s.positive("max_episode_steps", c.max_episode_steps());
  s.non_negative("init_noise", c.init_noise());
}

}  // namespace

void check_config(const config::CartpoleConfig& c) { check_in_code(c, "task.cartpole", check_cartpole); }

namespace robots::cartpole {

TaskSpec cartpole_spec(const config::TaskConfig& cfg) {
  TaskSpec s;
  s.name = "cartpole";
  s.obs_dim = 5;  // x, cos th, sin th, xdot, thdot
  s.act_dim = 1;
  s.max_episode_steps = cfg.cartpole().max_episode_steps();
  s.metric_names = {"upright_fraction"};
  s.reward_bound = 1;  // the control suite's smooth reward: a product of factors in [0, 1]
  s.reward_min = 0;
  return s;
}

void check_cartpole(const config_checks::Section& task, const config::TaskConfig& t) {
  farm::check_cartpole(task.nest("cartpole", t.cartpole()), t.cartpole());
}

}  // namespace robots::cartpole

}  // namespace farm
