#include "pendulum/pendulum_task.h"

#include <mujoco/mujoco.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "embedded_mjcf.h"
#include "pendulum/pendulum_spec.h"

namespace farm::robots {

namespace {

constexpr double kPi = 3.14159265358979323846;
// Axial inertia of the rod: any small positive value, the hinge never turns about that axis.
constexpr double kAxialInertia = 1e-6;

// Pendulum-v1's angle_normalize: ((x + pi) mod 2 pi) - pi with a non-negative modulo.
double angle_normalize(double x) {
  double r = std::fmod(x + kPi, 2 * kPi);
  if (r < 0) r += 2 * kPi;
  return r - kPi;
}

PendulumState& as_pendulum(TaskState& s) { return static_cast<PendulumState&>(s); }
const PendulumState& as_pendulum(const TaskState& s) { return static_cast<const PendulumState&>(s); }

}  // namespace

PendulumTask::PendulumTask(const config::PendulumConfig& cfg) : cfg_(cfg) {
  // The loader has checked a config read from a file; this one may have been built in code.
  check_config(cfg);

  spec_.name = "pendulum";
  spec_.obs_dim = 3;
  spec_.act_dim = 1;
  spec_.max_episode_steps = cfg.max_episode_steps();
  spec_.metric_names = {"upright_fraction"};

  model_ = load_embedded_model("pendulum/pendulum.xml");
  mjModel* m = model_;
  if (m->nq != 1 || m->nv != 1 || m->nu != 1 || m->nbody != 2 || m->ngeom != 1) {
    mj_deleteModel(m);
    throw std::runtime_error("pendulum/pendulum.xml: expected one hinge, one motor, one body");
  }
  // The config is the source of truth: every field below replaces what the XML compiled.
  const double g = cfg.gravity(), mass = cfg.mass(), l = cfg.length();
  m->opt.timestep = cfg.dt();
  m->opt.gravity[0] = 0;
  m->opt.gravity[1] = 0;
  m->opt.gravity[2] = -g;
  const int b = 1;  // the rod; body 0 is the world
  m->body_mass[b] = mass;
  m->body_ipos[3 * b + 0] = 0;
  m->body_ipos[3 * b + 1] = 0;
  m->body_ipos[3 * b + 2] = l / 2;
  m->body_inertia[3 * b + 0] = mass * l * l / 12;
  m->body_inertia[3 * b + 1] = mass * l * l / 12;
  m->body_inertia[3 * b + 2] = kAxialInertia;
  m->actuator_ctrlrange[0] = -cfg.max_torque();
  m->actuator_ctrlrange[1] = cfg.max_torque();
  // Drawn geometry follows the length so renders show the simulated rod.
  m->geom_pos[2] = l / 2;
  m->geom_size[1] = l / 2;
  m->geom_rbound[0] = l / 2 + m->geom_size[0];
  // Derived constants (subtree masses, reference inertias) depend on what was just changed.
  mjData* d = mj_makeData(m);
  mj_setConst(m, d);
  mj_deleteData(d);
}

PendulumTask::~PendulumTask() {
  if (model_) mj_deleteModel(model_);
}

std::unique_ptr<TaskState> PendulumTask::make_state() const {
  auto s = std::make_unique<PendulumState>();
  s->data = mj_makeData(model_);
  if (!s->data) throw std::runtime_error("pendulum: mj_makeData failed");
  return s;
}

void PendulumTask::write_obs(const TaskState& s, float* obs) const {
  const double th = s.data->qpos[0];
  obs[0] = float(std::cos(th));
  obs[1] = float(std::sin(th));
  obs[2] = float(s.data->qvel[0]);
}

void PendulumTask::reset(TaskState& s, uint64_t seed, float* obs) const {
  PendulumState& ps = as_pendulum(s);
  mj_resetData(model_, ps.data);
  ps.rng.seed(seed);
  std::uniform_real_distribution<double> angle_dist(-kPi, kPi);
  std::uniform_real_distribution<double> speed_dist(-cfg_.init_max_speed(), cfg_.init_max_speed());
  ps.data->qpos[0] = angle_dist(ps.rng);
  ps.data->qvel[0] = speed_dist(ps.rng);
  ps.step = 0;
  ps.episode_return = 0.0;
  ps.upright_steps = 0;
  write_obs(ps, obs);
}

void PendulumTask::set_state(TaskState& s, double th, double thdot, float* obs) const {
  s.data->qpos[0] = th;
  s.data->qvel[0] = thdot;
  write_obs(s, obs);
}

double PendulumTask::angle(const TaskState& s) { return s.data->qpos[0]; }
double PendulumTask::velocity(const TaskState& s) { return s.data->qvel[0]; }

StepResult PendulumTask::step(TaskState& s, const float* action, float* obs) const {
  PendulumState& ps = as_pendulum(s);
  mjData* d = ps.data;
  // A NaN action (diverged policy) would poison the simulation state; treat it as no torque.
  const double a = std::isnan(action[0]) ? 0.0 : std::clamp(double(action[0]), -1.0, 1.0);
  const double u = a * cfg_.max_torque();
  const double th = d->qpos[0], thdot = d->qvel[0];
  const double th_n = angle_normalize(th);
  const double cost = th_n * th_n + cfg_.velocity_cost() * thdot * thdot + cfg_.torque_cost() * u * u;

  d->ctrl[0] = u;
  mj_step(model_, d);
  // Pendulum-v1 clips the new velocity before integrating the angle with it; MuJoCo has
  // already integrated with the unclipped one, so redo the position update when clipping.
  const double max_speed = cfg_.max_speed();
  if (std::abs(d->qvel[0]) > max_speed) {
    d->qvel[0] = std::clamp(d->qvel[0], -max_speed, max_speed);
    d->qpos[0] = th + d->qvel[0] * model_->opt.timestep;
  }
  if (s.after_physics_step) s.after_physics_step();
  write_obs(ps, obs);

  StepResult r;
  r.reward = float(-cost);
  ps.step += 1;
  ps.episode_return += -cost;
  if (std::cos(d->qpos[0]) > kUprightCos) ps.upright_steps += 1;
  r.truncated = ps.step >= cfg_.max_episode_steps();
  return r;
}

void PendulumTask::episode_metrics(const TaskState& s, float* out) const {
  const PendulumState& ps = as_pendulum(s);
  out[0] = ps.step > 0 ? float(ps.upright_steps) / float(ps.step) : 0.f;
}

std::unique_ptr<Task> pendulum::make_pendulum_task(const config::TaskConfig& cfg) {
  return std::make_unique<PendulumTask>(cfg.pendulum());
}

}  // namespace farm::robots
