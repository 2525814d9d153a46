#include "quadruped/quadruped_task.h"

#include <mujoco/mujoco.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "embedded_mjcf.h"
#include "quadruped/quadruped_spec.h"

namespace farm::robots::quadruped {

namespace {

constexpr double kPi = 3.14159265358979323846;
const char* kLegNames[4] = {"FL", "FR", "RL", "RR"};
constexpr double kContactForce = 1.0;  // N: a foot with more normal force is on the ground (legged_gym)

double wrap_pi(double a) { return std::remainder(a, 2 * kPi); }

struct RobotInfo {
  const char* task_name;
  const char* mjcf;
  bool spine;
  bool badger;
};

RobotInfo info(Robot r) {
  switch (r) {
    case Robot::kA1:
      return {"a1", "quadruped/a1.xml", false, false};
    case Robot::kHoneyBadger:
      return {"honey_badger", "quadruped/honey_badger.xml", false, true};
    case Robot::kSilverBadger:
      return {"silver_badger", "quadruped/silver_badger.xml", true, true};
  }
  throw std::invalid_argument("unknown robot");
}

// The Badger values of LeggedConfig (MushroomRL paper §3.4), applied where the config leaves a field unset.
config::LeggedConfig with_robot_defaults(Robot r, config::LeggedConfig c) {
  if (!info(r).badger) return c;
  if (!c.has_heading_command()) c.set_heading_command(false);       // MushroomRL paper §3.4: yaw rate drawn directly
  if (!c.has_randomize_dynamics()) c.set_randomize_dynamics(true);  // MushroomRL paper §3.4
  if (!c.has_kp()) c.set_kp(40.0);  // at 20 the heavier robot sags 7 cm (tests/unit/test_quadruped.cpp stands it)
  if (!c.has_kd()) c.set_kd(1.0);
  auto* w = c.mutable_reward();
  if (!w->has_base_height()) w->set_base_height(-10.0);                   // MushroomRL paper §3.4: goal height 0.3
  if (!w->has_feet_pair_off_ground()) w->set_feet_pair_off_ground(-0.5);  // MushroomRL paper §3.4
  return c;
}

}  // namespace

QuadrupedState::~QuadrupedState() {
  if (model) mj_deleteModel(model);
}

QuadrupedTask::QuadrupedTask(Robot robot, const config::LeggedConfig& cfg)
    : robot_(robot), cfg_(with_robot_defaults(robot, cfg)) {
  const RobotInfo ri = info(robot);
  // The loader has checked a config read from a file; this one may have been built in code.
  check_config(cfg_, ri.task_name);
  model_ = load_embedded_model(ri.mjcf);
  model_->opt.timestep = cfg_.physics_dt();
  using namespace legged;
  static const char* kJointParts[3] = {"hip", "thigh", "calf"};
  for (const char* leg : kLegNames)
    for (const char* part : kJointParts) joints_.push_back(joint_id(model_, std::string(leg) + "_" + part + "_joint"));
  if (ri.spine) joints_.push_back(joint_id(model_, "spine"));
  const int key = mj_name2id(model_, mjOBJ_KEY, "home");
  if (key < 0) throw std::runtime_error(std::string(ri.mjcf) + ": no keyframe named 'home'");
  home_qpos_.assign(model_->key_qpos + key * model_->nq, model_->key_qpos + (key + 1) * model_->nq);
  for (int j : joints_) {
    dofs_.push_back(model_->jnt_dofadr[j]);
    qpos_adr_.push_back(model_->jnt_qposadr[j]);
    default_pose_.push_back(home_qpos_[model_->jnt_qposadr[j]]);
    int act = -1;
    for (int a = 0; a < model_->nu; ++a)
      if (model_->actuator_trnid[2 * a] == j) act = a;
    if (act < 0)
      throw std::runtime_error(std::string(ri.mjcf) + ": joint " + mj_id2name(model_, mjOBJ_JOINT, j) +
                               " has no actuator");
    actuators_.push_back(act);
    nominal_torque_limit_.push_back(model_->actuator_ctrlrange[2 * act + 1]);
    const double lo = model_->jnt_range[2 * j], hi = model_->jnt_range[2 * j + 1];
    const double mid = 0.5 * (lo + hi), half = 0.5 * (hi - lo) * cfg_.soft_dof_pos_limit();
    soft_lower_.push_back(mid - half);
    soft_upper_.push_back(mid + half);
  }
  trunk_body_ = body_id(model_, "trunk");
  std::vector<std::string> trunk_geoms = {"trunk_geom"}, leg_geoms, foot_names;
  if (ri.spine) {
    rear_trunk_body_ = body_id(model_, "trunk_rear");
    trunk_geoms.push_back("trunk_rear_geom");
  }
  for (const char* leg : kLegNames) {
    // The hip housings stick out past the trunk box: pitched nose-down, the trunk rests on them
    // with its centre well above min_base_height. That is a fall, not a stance: A1 policies
    // trained without this knelt on the front hips, turned in place and never walked.
    trunk_geoms.push_back(std::string(leg) + "_hip_geom");
    leg_geoms.push_back(std::string(leg) + "_thigh_geom");
    leg_geoms.push_back(std::string(leg) + "_calf_geom");
    foot_names.push_back(std::string(leg) + "_foot");
  }
  feet_ = make_group(model_, "feet", foot_names);
  legs_ = make_group(model_, "thighs_calves", leg_geoms);
  trunk_ = make_group(model_, "trunk", trunk_geoms);
  floor_ = make_group(model_, "floor", {"floor"});
  foot_geoms_ = feet_.geoms;

  const int n = num_joints();
  obs_spec_.add(
      {"base_lin_vel", Property::kBodyLinVelLocal, {trunk_body_}, 0, cfg_.obs_lin_vel(), {}, cfg_.noise_lin_vel()});
  obs_spec_.add(
      {"base_ang_vel", Property::kBodyAngVelLocal, {trunk_body_}, 0, cfg_.obs_ang_vel(), {}, cfg_.noise_ang_vel()});
  obs_spec_.add({"projected_gravity", Property::kProjectedGravity, {trunk_body_}, 0, 1.0, {}, cfg_.noise_gravity()});
  // Commands are scaled as legged_gym's (lin_vel, lin_vel, ang_vel scales), without noise: a custom
  // slot over [-1/scale, 1/scale] maps x to x * scale.
  obs_spec_.add(
      {"command_lin", Property::kCustom, {}, 2, 1.0, {}, 0.0, -1.0 / cfg_.obs_lin_vel(), 1.0 / cfg_.obs_lin_vel()});
  obs_spec_.add(
      {"command_yaw", Property::kCustom, {}, 1, 1.0, {}, 0.0, -1.0 / cfg_.obs_ang_vel(), 1.0 / cfg_.obs_ang_vel()});
  obs_spec_.add({"dof_pos", Property::kJointPos, joints_, 0, cfg_.obs_dof_pos(), default_pose_, cfg_.noise_dof_pos()});
  obs_spec_.add({"dof_vel", Property::kJointVel, joints_, 0, cfg_.obs_dof_vel(), {}, cfg_.noise_dof_vel()});
  obs_spec_.add({"last_action", Property::kCustom, {}, n, 1.0, {}, 0.0, -1.0, 1.0});
  if (ri.badger) {
    obs_spec_.add({"base_height", Property::kBodyHeight, {trunk_body_}, 0, cfg_.obs_height(), {}, cfg_.noise_height()});
    obs_spec_.add({"dynamics", Property::kCustom, {}, kNumDynamicsParams, 1.0, {}, cfg_.noise_params(), -1.0, 1.0});
  }
  spec_.name = ri.task_name;
  spec_.obs_dim = obs_spec_.dim();
  spec_.act_dim = n;
  spec_.max_episode_steps = cfg_.max_episode_steps();
  spec_.metric_names = {"tracking_lin", "tracking_ang", "lin_vel_error", "fell", "time_s"};
}

QuadrupedTask::~QuadrupedTask() {
  if (model_) mj_deleteModel(model_);
}

const mjModel* QuadrupedTask::model_of(const TaskState& s) const { return static_cast<const QuadrupedState&>(s).model; }

std::unique_ptr<TaskState> QuadrupedTask::make_state() const {
  auto s = std::make_unique<QuadrupedState>();
  s->model = mj_copyModel(nullptr, model_);
  s->data = mj_makeData(s->model);
  const size_t n = joints_.size();
  s->last_action.assign(n, 0.0);
  s->last_dof_vel.assign(n, 0.0);
  s->targets.assign(n, 0.0);
  s->torques.assign(n, 0.0);
  s->torque_limit = nominal_torque_limit_;
  s->action.assign(n, 0.0);
  // command_lin, command_yaw, last_action (and for the Badgers the dynamics parameters).
  s->custom_obs = {std::vector<double>(2), std::vector<double>(1), std::vector<double>(n)};
  if (info(robot_).badger) s->custom_obs.emplace_back(kNumDynamicsParams);
  return s;
}

void QuadrupedTask::sample_command(QuadrupedState& s) const {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  auto small = [&](double v) { return std::abs(v) < cfg_.small_command() ? 0.0 : v; };
  s.command[0] = small(cfg_.lin_vel_x_max() * u(s.rng));
  s.command[1] = small(cfg_.lin_vel_y_max() * u(s.rng));
  if (cfg_.heading_command()) {
    s.heading_target = kPi * u(s.rng);
    s.command[2] = heading_yaw_rate(s.heading_target, heading(s));
  } else {
    s.command[2] = cfg_.ang_vel_max() * u(s.rng);
  }
}

double QuadrupedTask::heading_yaw_rate(double heading_target, double heading) const {
  return std::clamp(cfg_.heading_gain() * wrap_pi(heading_target - heading), -cfg_.ang_vel_max(), cfg_.ang_vel_max());
}

double QuadrupedTask::heading(const QuadrupedState& s) const {
  const mjtNum* q = s.data->qpos + 3;  // the trunk's free joint comes first
  // x axis of the body in the world: first column of the rotation matrix.
  const double fx = 1 - 2 * (q[2] * q[2] + q[3] * q[3]);
  const double fy = 2 * (q[1] * q[2] + q[0] * q[3]);
  return std::atan2(fy, fx);
}

void QuadrupedTask::randomize(QuadrupedState& s) const {
  mjModel* m = s.model;
  const mjModel* b = model_;
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  auto& p = s.dynamics;
  p.fill(0.0);
  // Foot friction (MushroomRL paper §3.3, every robot), min + (max - min) x U(0, 1), as the task of terms
  // draws it, so that the two give the same physics from the same seed.
  const double share = std::uniform_real_distribution<double>(0.0, 1.0)(s.rng);
  p[0] = 2 * share - 1;
  const double friction = cfg_.friction_min() + (cfg_.friction_max() - cfg_.friction_min()) * share;
  for (int g : foot_geoms_) m->geom_friction[3 * g] = friction;
  for (int p = 0; p < m->npair; ++p) mix_pair_friction(m, p);  // the quadruped MJCFs' <contact> pairs
  s.kp = cfg_.kp();
  s.kd = cfg_.kd();
  s.action_scale = cfg_.action_scale();
  s.torque_multiplier = 1.0;
  s.velocity_limit = cfg_.velocity_limit();
  s.torque_limit = nominal_torque_limit_;
  if (!cfg_.randomize_dynamics()) return;
  // The MushroomRL paper §3.4: trunk mass, centre of mass, torque and velocity limits, foot size, joint
  // damping / stiffness / armature / friction loss, PD gains, action scale, torque multiplier.
  for (int i = 1; i < kNumDynamicsParams; ++i) p[i] = u(s.rng);
  for (int body : {trunk_body_, rear_trunk_body_}) {
    if (body < 0) continue;
    const double k = 1 + cfg_.trunk_mass_rel() * p[1];
    m->body_mass[body] = b->body_mass[body] * k;
    for (int a = 0; a < 3; ++a) {
      m->body_inertia[3 * body + a] = b->body_inertia[3 * body + a] * k;
      m->body_ipos[3 * body + a] = b->body_ipos[3 * body + a] + cfg_.com_shift() * p[2 + a];
    }
  }
  for (size_t j = 0; j < joints_.size(); ++j)
    s.torque_limit[j] = nominal_torque_limit_[j] * (1 + cfg_.torque_limit_rel() * p[5]);
  s.velocity_limit = cfg_.velocity_limit() * (1 + cfg_.velocity_limit_rel() * p[6]);
  for (int g : foot_geoms_) {
    m->geom_size[3 * g] = b->geom_size[3 * g] * (1 + cfg_.foot_size_rel() * p[7]);
    m->geom_rbound[g] = b->geom_rbound[g] * (1 + cfg_.foot_size_rel() * p[7]);
  }
  auto unit = [](double x) { return 0.5 * (x + 1); };  // [-1, 1] -> [0, 1]
  for (size_t j = 0; j < joints_.size(); ++j) {
    const int dof = dofs_[j];
    m->dof_damping[dof] = cfg_.joint_damping_max() * unit(p[8]);
    m->jnt_stiffness[joints_[j]] = cfg_.joint_stiffness_max() * unit(p[9]);
    m->dof_armature[dof] = 0.005 + (cfg_.armature_max() - 0.005) * unit(p[10]);
    m->dof_frictionloss[dof] = cfg_.frictionloss_max() * unit(p[11]);
  }
  s.kp = cfg_.kp() * (1 + cfg_.kp_rel() * p[12]);
  s.kd = cfg_.kd() * (1 + cfg_.kd_rel() * p[13]);
  s.action_scale = cfg_.action_scale() * (1 + cfg_.action_scale_rel() * p[14]);
  s.torque_multiplier = 1 + cfg_.torque_multiplier_rel() * p[15];
}

void QuadrupedTask::reset(TaskState& base, uint64_t seed, float* obs) const {
  auto& s = static_cast<QuadrupedState&>(base);
  s.rng.seed(seed);
  s.step = 0;
  s.episode_return = 0;
  randomize(s);
  mjData* d = s.data;
  mj_resetData(s.model, d);
  std::copy(home_qpos_.begin(), home_qpos_.end(), d->qpos);
  // legged_gym reset: joints at the default pose times U(0.5, 1.5), base velocities U(-0.5, 0.5).
  std::uniform_real_distribution<double> scale(cfg_.init_joint_scale_min(), cfg_.init_joint_scale_max());
  for (size_t j = 0; j < joints_.size(); ++j) {
    const int jid = joints_[j];
    const double q = default_pose_[j] * scale(s.rng);
    d->qpos[qpos_adr_[j]] = std::clamp(q, s.model->jnt_range[2 * jid], s.model->jnt_range[2 * jid + 1]);
  }
  // The scaled pose can put a foot below the floor (a flexed thigh with a clamped calf reaches
  // further down than the default pose): lift the base so the lowest foot starts just above it,
  // as legged_gym's drop from 0.42 m does, instead of the contact solver throwing the robot.
  mj_kinematics(s.model, d);
  double lowest = std::numeric_limits<double>::infinity();
  for (int g : foot_geoms_) lowest = std::min(lowest, d->geom_xpos[3 * g + 2] - s.model->geom_size[3 * g]);
  if (lowest < cfg_.init_foot_clearance()) d->qpos[2] += cfg_.init_foot_clearance() - lowest;
  std::uniform_real_distribution<double> vel(-cfg_.init_base_vel(), cfg_.init_base_vel());
  for (int k = 0; k < 6; ++k) d->qvel[k] = vel(s.rng);
  mj_forward(s.model, d);
  std::fill(s.last_action.begin(), s.last_action.end(), 0.0);
  for (size_t j = 0; j < joints_.size(); ++j) s.last_dof_vel[j] = d->qvel[dofs_[j]];
  s.targets = default_pose_;
  std::fill(s.torques.begin(), s.torques.end(), 0.0);
  s.feet_air_time.fill(0.0);
  s.last_contact.fill(false);
  s.push_every_steps =
      cfg_.push_interval_s() > 0 ? std::max(1, int(std::lround(cfg_.push_interval_s() / policy_dt()))) : 0;
  s.sum_tracking_lin = s.sum_tracking_ang = s.sum_lin_error = 0;
  s.fell = false;
  sample_command(s);
  write_obs(s, obs);
}

void QuadrupedTask::pd_control(QuadrupedState& s, mjData* d) const {
  // PD law on every physics step (MushroomRL paper §3.3), scaled by the torque multiplier and clipped to
  // the torque limit; no torque that drives a joint further past its speed limit.
  for (size_t j = 0; j < joints_.size(); ++j) {
    const double q = d->qpos[qpos_adr_[j]], qd = d->qvel[dofs_[j]];
    double tau = s.torque_multiplier * (s.kp * (s.targets[j] - q) - s.kd * qd);
    tau = std::clamp(tau, -s.torque_limit[j], s.torque_limit[j]);
    if (std::abs(qd) > s.velocity_limit && tau * qd > 0) tau = 0;
    s.torques[j] = tau;
    d->ctrl[actuators_[j]] = tau;
  }
}

RewardTerms QuadrupedTask::reward_terms(const QuadrupedState& s, const std::vector<double>& a,
                                        const std::array<bool, 4>& first_contact,
                                        const std::array<bool, 4>& contact_filt) const {
  using legged::Property;
  const mjModel* m = s.model;
  const mjData* d = s.data;
  double v[3], w[3], g[3], z;
  legged::read_property(m, d, Property::kBodyLinVelLocal, trunk_body_, v);
  legged::read_property(m, d, Property::kBodyAngVelLocal, trunk_body_, w);
  legged::read_property(m, d, Property::kProjectedGravity, trunk_body_, g);
  legged::read_property(m, d, Property::kBodyHeight, trunk_body_, &z);
  RewardTerms t;
  const double ex = s.command[0] - v[0], ey = s.command[1] - v[1], ew = s.command[2] - w[2];
  t.tracking_lin_vel = std::exp(-(ex * ex + ey * ey) / cfg_.tracking_sigma());
  t.tracking_ang_vel = std::exp(-ew * ew / cfg_.tracking_sigma());
  t.lin_vel_z = v[2] * v[2];
  t.ang_vel_xy = w[0] * w[0] + w[1] * w[1];
  t.orientation = g[0] * g[0] + g[1] * g[1];
  t.collision = legged::count_touching(m, d, legs_, floor_);
  const double dt = policy_dt();
  for (size_t j = 0; j < joints_.size(); ++j) {
    const double q = d->qpos[qpos_adr_[j]], qd = d->qvel[dofs_[j]];
    t.dof_pos_limits += std::max(0.0, soft_lower_[j] - q) + std::max(0.0, q - soft_upper_[j]);
    t.torques += s.torques[j] * s.torques[j];
    const double acc = (s.last_dof_vel[j] - qd) / dt;
    t.dof_acc += acc * acc;
    const double da = s.last_action[j] - a[j];
    t.action_rate += da * da;
  }
  // legged_gym feet air time: on touchdown, reward the flight time beyond the target, only while
  // the robot is asked to move.
  const bool moving = std::hypot(s.command[0], s.command[1]) > 0.1;
  for (int f = 0; f < kLegs; ++f)
    if (first_contact[f]) t.feet_air_time += s.feet_air_time[f] - cfg_.feet_air_time_target();
  if (!moving) t.feet_air_time = 0;
  t.base_height = (z - cfg_.base_height_target()) * (z - cfg_.base_height_target());
  // The MushroomRL paper §3.4: both front feet (FL, FR) or both rear feet (RL, RR) in the air.
  // With legged_gym's one-step contact filter, as for the air time (contact_filt, from step()): a
  // foot counts as down if it touched on this step or the one before. Raw contacts flicker at a
  // trot's diagonal hand-over, and the raw term fired on 5-19 % of the steps of a walking A1 gait
  // (0-3 % filtered).
  const auto& down = contact_filt;
  t.feet_pair_off_ground = double(!down[0] && !down[1]) + double(!down[2] && !down[3]);
  return t;
}

double QuadrupedTask::total_reward(const RewardTerms& t) const {
  const auto& w = cfg_.reward();
  const double r = w.tracking_lin_vel() * t.tracking_lin_vel + w.tracking_ang_vel() * t.tracking_ang_vel +
                   w.lin_vel_z() * t.lin_vel_z + w.ang_vel_xy() * t.ang_vel_xy + w.collision() * t.collision +
                   w.dof_pos_limits() * t.dof_pos_limits + w.torques() * t.torques + w.dof_acc() * t.dof_acc +
                   w.action_rate() * t.action_rate + w.feet_air_time() * t.feet_air_time +
                   w.base_height() * t.base_height + w.feet_pair_off_ground() * t.feet_pair_off_ground +
                   w.orientation() * t.orientation;
  const double scaled = r * policy_dt();
  return cfg_.only_positive_rewards() ? std::max(0.0, scaled) : scaled;
}

StepResult QuadrupedTask::step(TaskState& base, const float* action, float* obs) const {
  auto& s = static_cast<QuadrupedState&>(base);
  mjData* d = s.data;
  const size_t n = joints_.size();
  std::vector<double>& a = s.action;
  for (size_t j = 0; j < n; ++j) {
    // A NaN action (diverged policy) would poison the simulation and the observed last action; it
    // means the default pose. std::clamp passes NaN through.
    const double aj = std::isnan(action[j]) ? 0.0 : std::clamp(double(action[j]), -1.0, 1.0);
    a[j] = aj * cfg_.action_range();  // legged_gym's units
    s.targets[j] = default_pose_[j] + s.action_scale * a[j];
  }
  legged::ControlHooks hooks;
  if (s.after_physics_step) hooks.after = [&s](mjData*) { s.after_physics_step(); };
  legged::control_steps(
      s.model, d, cfg_.decimation(), [&](mjData* dd) { pd_control(s, dd); }, hooks);
  ++s.step;
  StepResult r;
  bool finite = true;
  for (int i = 0; i < s.model->nq && finite; ++i) finite = std::isfinite(d->qpos[i]);
  for (int i = 0; i < s.model->nv && finite; ++i) finite = std::isfinite(d->qvel[i]) && std::abs(d->qvel[i]) < 1e3;
  if (!finite) {
    // Diverged: end the episode as a fall; the observation is the reset-free last sane one (zeros).
    s.fell = true;
    r.terminated = true;
    std::fill(obs, obs + spec_.obs_dim, 0.f);
    return r;
  }
  // Random pushes (MushroomRL paper §3.3): a velocity kick to the trunk.
  if (s.push_every_steps > 0 && s.step % s.push_every_steps == 0) {
    std::uniform_real_distribution<double> push(-cfg_.push_max_vel(), cfg_.push_max_vel());
    d->qvel[0] += push(s.rng);
    d->qvel[1] += push(s.rng);
  }
  // Commands: resampled with probability command_resample_prob per step (MushroomRL paper §3.3).
  if (std::uniform_real_distribution<double>(0, 1)(s.rng) < cfg_.command_resample_prob()) sample_command(s);
  if (cfg_.heading_command()) s.command[2] = heading_yaw_rate(s.heading_target, heading(s));

  std::vector<double>& forces = s.foot_forces;
  legged::net_contact_forces(s.model, d, feet_, forces);
  std::array<bool, 4> first_contact{}, filt{};
  const double dt = policy_dt();
  for (int f = 0; f < kLegs; ++f) {
    const bool contact = forces[3 * f + 2] > kContactForce;
    filt[f] = contact || s.last_contact[f];  // legged_gym: contacts are unreliable on one step
    first_contact[f] = s.feet_air_time[f] > 0 && filt[f];
    s.feet_air_time[f] += dt;
    s.last_contact[f] = contact;
  }
  const RewardTerms t = reward_terms(s, a, first_contact, filt);
  for (int f = 0; f < kLegs; ++f)
    if (filt[f]) s.feet_air_time[f] = 0;
  r.reward = float(total_reward(t));
  s.sum_tracking_lin += t.tracking_lin_vel;
  s.sum_tracking_ang += t.tracking_ang_vel;
  {
    double v[3];
    legged::read_property(s.model, d, legged::Property::kBodyLinVelLocal, trunk_body_, v);
    s.sum_lin_error += std::hypot(s.command[0] - v[0], s.command[1] - v[1]);
  }
  if (fallen(s)) {
    s.fell = true;
    r.terminated = true;
    r.reward += float(cfg_.reward().termination() * policy_dt());  // after the clip, as legged_gym adds it
  } else if (s.step >= cfg_.max_episode_steps()) {
    r.truncated = true;
  }
  s.episode_return += r.reward;
  s.last_action = a;
  for (size_t j = 0; j < n; ++j) s.last_dof_vel[j] = d->qvel[dofs_[j]];
  write_obs(s, obs);
  return r;
}

bool QuadrupedTask::fallen(const QuadrupedState& s) const {
  double z;
  legged::read_property(s.model, s.data, legged::Property::kBodyHeight, trunk_body_, &z);
  // The MushroomRL paper §3.3: the episode ends when the trunk (with its hip housings) touches the ground.
  return legged::touching(s.model, s.data, trunk_, floor_) || z < cfg_.min_base_height();
}

void QuadrupedTask::write_obs(QuadrupedState& s, float* obs) const {
  auto& custom = s.custom_obs;  // slots in the order obs_spec_ lists them, sized by make_state
  custom[0][0] = s.command[0];
  custom[0][1] = s.command[1];
  custom[1][0] = s.command[2];
  for (size_t j = 0; j < joints_.size(); ++j) custom[2][j] = s.last_action[j] / cfg_.action_range();
  if (custom.size() > 3) std::copy(s.dynamics.begin(), s.dynamics.end(), custom[3].begin());
  legged::build_observation(s.model, s.data, obs_spec_, custom, cfg_.noise_level(), s.rng, obs);
}

void QuadrupedTask::episode_metrics(const TaskState& base, float* out) const {
  const auto& s = static_cast<const QuadrupedState&>(base);
  const double steps = std::max(1, s.step);
  out[0] = float(s.sum_tracking_lin / steps);
  out[1] = float(s.sum_tracking_ang / steps);
  out[2] = float(s.sum_lin_error / steps);
  out[3] = s.fell ? 1.f : 0.f;
  out[4] = float(s.step * policy_dt());
}

std::unique_ptr<Task> make_a1_task(const config::TaskConfig& cfg) {
  return std::make_unique<QuadrupedTask>(Robot::kA1, cfg.a1());
}
std::unique_ptr<Task> make_honey_badger_task(const config::TaskConfig& cfg) {
  return std::make_unique<QuadrupedTask>(Robot::kHoneyBadger, cfg.honey_badger());
}
std::unique_ptr<Task> make_silver_badger_task(const config::TaskConfig& cfg) {
  return std::make_unique<QuadrupedTask>(Robot::kSilverBadger, cfg.silver_badger());
}

void QuadrupedTask::view(const TaskState& base, const mjData* pose, int root, TaskView& out) const {
  const auto& s = static_cast<const QuadrupedState&>(base);
  out.elevation = -20;
  command_view(s.command.data(), pose, root, out);
}

}  // namespace farm::robots::quadruped
