#include "cartpole/cartpole_task.h"

#include <mujoco/mujoco.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "cartpole/cartpole_spec.h"
#include "embedded_mjcf.h"

namespace farm::robots {

namespace {

constexpr double kPi = 3.14159265358979323846;

// dm_control's rewards.tolerance with bounds (0, 0): gaussian sigmoid, value 0.1 at the margin.
double gaussian_tolerance(double x, double margin) {
  const double d = x / margin;
  return std::pow(0.1, d * d);
}

}  // namespace

CartpoleTask::CartpoleTask(const config::CartpoleConfig& cfg) : cfg_(cfg) {
  // The loader has checked a config read from a file; this one may have been built in code.
  check_config(cfg);
  spec_.name = "cartpole";
  spec_.obs_dim = 5;
  spec_.act_dim = 1;
  spec_.max_episode_steps = cfg.max_episode_steps();
  spec_.metric_names = {"upright_fraction"};
  model_ = load_embedded_model("cartpole/cartpole.xml");
  mjModel* m = model_;
  if (m->nq != 2 || m->nv != 2 || m->nu != 1 || m->njnt != 2) {
    mj_deleteModel(m);
    throw std::runtime_error("cartpole/cartpole.xml: expected a slider, a hinge and one motor");
  }
  m->opt.timestep = cfg.physics_dt();
  m->actuator_gear[0] = cfg.gear() * cfg.max_force();
  m->jnt_range[0] = -cfg.rail_limit();
  m->jnt_range[1] = cfg.rail_limit();
}

CartpoleTask::~CartpoleTask() {
  if (model_) mj_deleteModel(model_);
}

std::unique_ptr<TaskState> CartpoleTask::make_state() const {
  auto s = std::make_unique<CartpoleState>();
  s->data = mj_makeData(model_);
  if (!s->data) throw std::runtime_error("cartpole: mj_makeData failed");
  return s;
}

void CartpoleTask::write_obs(const TaskState& s, float* obs) const {
  const mjData* d = s.data;
  obs[0] = float(d->qpos[0]);
  obs[1] = float(std::cos(d->qpos[1]));
  obs[2] = float(std::sin(d->qpos[1]));
  obs[3] = float(d->qvel[0]);
  obs[4] = float(d->qvel[1]);
}

void CartpoleTask::reset(TaskState& s, uint64_t seed, float* obs) const {
  auto& cs = static_cast<CartpoleState&>(s);
  mj_resetData(model_, cs.data);
  cs.rng.seed(seed);
  std::normal_distribution<double> noise(0.0, cfg_.init_noise());
  // dm_control swing-up: cart near the centre, pole hanging down, small noise everywhere.
  cs.data->qpos[0] = noise(cs.rng);
  cs.data->qpos[1] = kPi + noise(cs.rng);
  cs.data->qvel[0] = noise(cs.rng);
  cs.data->qvel[1] = noise(cs.rng);
  mj_forward(model_, cs.data);
  cs.step = 0;
  cs.episode_return = 0.0;
  cs.upright_steps = 0;
  write_obs(cs, obs);
}

double CartpoleTask::reward(double x, double cos_th, double thdot, double control) {
  const double upright = (cos_th + 1.0) / 2.0;
  const double centered = (1.0 + gaussian_tolerance(x, 2.0)) / 2.0;
  // tolerance(control, margin 1, value_at_margin 0, quadratic sigmoid) = 1 - u^2 on [-1, 1].
  const double small_control = (4.0 + std::max(0.0, 1.0 - control * control)) / 5.0;
  const double small_velocity = (1.0 + gaussian_tolerance(thdot, 5.0)) / 2.0;
  return upright * centered * small_control * small_velocity;
}

StepResult CartpoleTask::step(TaskState& s, const float* action, float* obs) const {
  auto& cs = static_cast<CartpoleState&>(s);
  mjData* d = cs.data;
  const double u = std::isnan(action[0]) ? 0.0 : std::clamp(double(action[0]), -1.0, 1.0);
  d->ctrl[0] = u;
  for (int k = 0; k < cfg_.control_substeps(); ++k) {
    mj_step(model_, d);
    if (s.after_physics_step) s.after_physics_step();
  }
  write_obs(cs, obs);
  const double c = std::cos(d->qpos[1]);
  StepResult r;
  r.reward = float(reward(d->qpos[0], c, d->qvel[1], u));
  cs.step += 1;
  cs.episode_return += r.reward;
  if (c > kUprightCos) cs.upright_steps += 1;
  r.truncated = cs.step >= cfg_.max_episode_steps();
  return r;
}

void CartpoleTask::episode_metrics(const TaskState& s, float* out) const {
  const auto& cs = static_cast<const CartpoleState&>(s);
  out[0] = cs.step > 0 ? float(cs.upright_steps) / float(cs.step) : 0.f;
}

std::unique_ptr<Task> cartpole::make_cartpole_task(const config::TaskConfig& cfg) {
  return std::make_unique<CartpoleTask>(cfg.cartpole());
}

}  // namespace farm::robots
