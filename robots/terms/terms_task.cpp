#include "terms/terms_task.h"

#include <muParser.h>
#include <mujoco/mujoco.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <stdexcept>

#include "terms/terms_library.h"

namespace farm::robots::terms {

namespace {

// mjVFS holds its file-name table inline (megabytes), too big for a thread's stack.
struct VfsDeleter {
  void operator()(mjVFS* v) const {
    mj_deleteVFS(v);
    delete v;
  }
};

std::string base_name(const std::string& p) { return p.substr(p.find_last_of('/') + 1); }

std::string name_of(const mjModel* m, mjtObj type, int id) {
  const char* n = mj_id2name(m, type, id);
  return n ? n : "";
}

// The scan the learner sized the task with must be the model MuJoCo compiled.
void check_scan(const ModelInfo& info, const mjModel* m, const std::string& model) {
  const auto differ = [&](const std::string& what) {
    throw ModelError(model + ": " + what +
                     " read from the MJCF differ from what MuJoCo compiled (a construct the farm's MJCF scan does not "
                     "follow; robots/terms/mjcf_bundle.cpp)");
  };
  if (int(info.bodies.size()) != m->nbody) differ("the bodies");
  for (int b = 1; b < m->nbody; ++b)
    if (info.bodies[b] != name_of(m, mjOBJ_BODY, b)) differ("the bodies");
  if (int(info.joints.size()) != m->njnt) differ("the joints");
  static const char* types[] = {"free", "ball", "slide", "hinge"};
  for (int j = 0; j < m->njnt; ++j)
    if (info.joints[j].name != name_of(m, mjOBJ_JOINT, j) || info.joints[j].type != types[m->jnt_type[j]])
      differ("the joints");
  if (int(info.actuators.size()) != m->nu) differ("the actuators");
  if (int(info.sensors.size()) != m->nsensor) differ("the sensors");
  for (int s = 0; s < m->nsensor; ++s)
    if (info.sensors[s].dim != m->sensor_dim[s] || info.sensors[s].name != name_of(m, mjOBJ_SENSOR, s))
      differ("the sensors");
}

}  // namespace

TermsState::~TermsState() {
  if (data) mj_deleteData(data);
  data = nullptr;
  if (model) mj_deleteModel(model);
}

mjModel* load_bundle(const config::TermsConfig& cfg) {
  check_bundle(cfg);
  std::unique_ptr<mjVFS, VfsDeleter> vfs(new mjVFS);
  mj_defaultVFS(vfs.get());
  for (const auto& f : cfg.model_files()) {
    const std::string name = base_name(f.path());
    if (mj_makeEmptyFileVFS(vfs.get(), name.c_str(), int(f.data().size())) != 0)
      throw ModelError(cfg.model() + ": could not add '" + f.path() + "' to MuJoCo's virtual file system");
    const int index = mj_findFileVFS(vfs.get(), name.c_str());
    if (index < 0) throw ModelError(cfg.model() + ": '" + f.path() + "' not found in MuJoCo's VFS after adding it");
    std::memcpy(vfs->filedata[index], f.data().data(), f.data().size());
  }
  char err[1000] = "";
  mjModel* m = mj_loadXML(base_name(cfg.model()).c_str(), vfs.get(), err, sizeof err);
  if (!m) throw ModelError(cfg.model() + ": " + (err[0] ? err : "MuJoCo could not load it"));
  return m;
}

TermsTask::TermsTask(const config::TermsConfig& cfg) : cfg_(cfg) {
  model_ = load_bundle(cfg_);  // checks the bundle first
  try {
    info_ = scan_model(cfg_);
    check_scan(info_, model_, cfg_.model());
    if (cfg_.physics_dt() > 0) model_->opt.timestep = cfg_.physics_dt();
    root_ = terms::root_body(cfg_, info_);
    bound_ = std::make_unique<Bound>();
    bind(cfg_, info_, model_, root_, *bound_);
    spec_ = task_spec(cfg_);
    for (int j = 0; j < model_->njnt; ++j) {
      if (model_->jnt_type[j] == mjJNT_FREE && model_->jnt_bodyid[j] == root_) {
        root_free_dof_ = model_->jnt_dofadr[j];
        root_free_qpos_ = model_->jnt_qposadr[j];
      }
      if (model_->jnt_type[j] == mjJNT_HINGE || model_->jnt_type[j] == mjJNT_SLIDE) scaled_joints_.push_back(j);
    }
    const auto& r = cfg_.reset();
    if (r.friction_geoms().empty()) {
      for (int g = 0; g < model_->ngeom; ++g) friction_geoms_.push_back(g);
    } else {
      friction_geoms_ = select(Names::Geoms, r.friction_geoms(), info_, root_);
    }
    for (int p = 0; p < model_->npair; ++p) {
      const auto& f = friction_geoms_;
      if (std::find(f.begin(), f.end(), model_->pair_geom1[p]) != f.end() ||
          std::find(f.begin(), f.end(), model_->pair_geom2[p]) != f.end())
        friction_pairs_.push_back(p);
    }
    if (!r.clear_geoms().empty()) clear_geoms_ = select(Names::Geoms, r.clear_geoms(), info_, root_);
  } catch (...) {
    mj_deleteModel(model_);
    throw;
  }
  default_qpos_.assign(model_->qpos0, model_->qpos0 + model_->nq);
  default_qvel_.assign(model_->nv, 0.0);
  const auto& a = cfg_.action();
  if (a.has_keyframe()) {
    const int k = mj_name2id(model_, mjOBJ_KEY, a.keyframe().c_str());
    if (k < 0) {
      mj_deleteModel(model_);
      throw std::invalid_argument("task.terms.action.keyframe: '" + a.keyframe() + "' is no keyframe of the model");
    }
    default_qpos_.assign(model_->key_qpos + k * model_->nq, model_->key_qpos + (k + 1) * model_->nq);
    default_qvel_.assign(model_->key_qvel + k * model_->nv, model_->key_qvel + (k + 1) * model_->nv);
  }
  if (a.type() == "position" && a.default_pose_size() > 0)
    for (size_t i = 0; i < bound_->target_qpos.size(); ++i)
      default_qpos_[bound_->target_qpos[i]] = a.default_pose(int(i));
  const auto& r = cfg_.reset();
  randomized_model_ = r.friction_min() != 1.0 || r.friction_max() != 1.0 || r.mass_min() != 1.0 || r.mass_max() != 1.0;
}

void TermsTask::randomize_model(TermsState& s) const {
  const auto& r = cfg_.reset();
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  s.model = s.model ? (mj_copyModel(s.model, model_), s.model) : mj_copyModel(nullptr, model_);
  mjModel* m = s.model;
  if (r.friction_min() != 1.0 || r.friction_max() != 1.0) {
    const double friction = r.friction_min() + (r.friction_max() - r.friction_min()) * unit(s.rng);
    for (int g : friction_geoms_) m->geom_friction[3 * g] = model_->geom_friction[3 * g] * friction;
    for (int p : friction_pairs_) mix_pair_friction(m, p);
  }
  if (r.mass_min() != 1.0 || r.mass_max() != 1.0) {
    for (int b = 1; b < model_->nbody; ++b) {
      const double k = r.mass_min() + (r.mass_max() - r.mass_min()) * unit(s.rng);
      m->body_mass[b] = model_->body_mass[b] * k;
      for (int i = 0; i < 3; ++i) m->body_inertia[3 * b + i] = model_->body_inertia[3 * b + i] * k;
    }
  }
}

namespace {
constexpr double kPi = 3.14159265358979323846;
}  // namespace

double TermsTask::heading_yaw_rate(const TermsState& s) const {
  mjtNum R[9];
  body_rotation(model_of(s), s.data, root_, R);
  const double heading = std::atan2(R[3], R[0]);  // the root's x axis in the world
  const auto& c = cfg_.command();
  return std::clamp(c.heading_gain() * std::remainder(s.heading_target - heading, 2 * kPi), c.yaw_rate_min(),
                    c.yaw_rate_max());
}

void TermsTask::sample_command(TermsState& s) const {
  const auto& c = cfg_.command();
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  const auto draw = [&](double lo, double hi) { return lo + (hi - lo) * unit(s.rng); };
  const auto planar = [&](double v) { return std::abs(v) < c.small_command() ? 0.0 : v; };
  s.command[0] = planar(draw(c.lin_vel_x_min(), c.lin_vel_x_max()));
  s.command[1] = planar(draw(c.lin_vel_y_min(), c.lin_vel_y_max()));
  if (c.heading()) {
    s.heading_target = draw(-kPi, kPi);
    s.command[2] = heading_yaw_rate(s);
  } else {
    s.command[2] = draw(c.yaw_rate_min(), c.yaw_rate_max());
  }
}

TermsTask::~TermsTask() {
  if (model_) mj_deleteModel(model_);
}

double TermsTask::agent_dt() const { return model_->opt.timestep * cfg_.control_substeps(); }

const mjModel* TermsTask::model_of(const TaskState& s) const {
  const auto& t = static_cast<const TermsState&>(s);
  return t.model ? t.model : model_;
}

std::unique_ptr<TaskState> TermsTask::make_state() const {
  auto s = std::make_unique<TermsState>();
  s->data = mj_makeData(model_);
  const int n = spec_.act_dim;
  s->action.assign(n, 0.0);
  s->last_action.assign(n, 0.0);
  s->targets.assign(n, 0.0);
  s->last_qvel.assign(model_->nv, 0.0);
  s->xpos_before.assign(3 * model_->nbody, 0.0);
  s->qpos_before.assign(model_->nq, 0.0);
  s->obs_raw.assign(spec_.obs_dim, 0.0);
  s->reward_sums.assign(cfg_.reward_size(), 0.0);
  s->value_sums.assign(cfg_.reward_size(), 0.0);
  s->air_time.resize(cfg_.reward_size());
  s->last_contact.resize(cfg_.reward_size());
  for (const auto& b : bound_->rewards) {
    s->air_time[b.slot].assign(b.contacts.geoms.size(), 0.0);
    s->last_contact[b.slot].assign(b.contacts.geoms.size(), 0);
  }
  const std::vector<std::string> names = expression_quantities(info_);
  s->quantities.assign(names.size(), 0.0);
  s->parsers.resize(cfg_.reward_size());
  for (const auto& b : bound_->rewards) {
    if (b.cfg->term() != "expression") continue;
    auto p = std::make_unique<mu::Parser>();
    for (size_t i = 0; i < names.size(); ++i) p->DefineVar(names[i], &s->quantities[i]);
    try {
      p->SetExpr(b.cfg->expression());
      p->Eval();
    } catch (const mu::Parser::exception_type& e) {
      throw std::invalid_argument("task.terms.reward[" + std::to_string(b.slot) + "].expression: " + e.GetMsg());
    }
    s->parsers[b.slot] = std::move(p);
  }
  return s;
}

void TermsTask::reset(TaskState& base, uint64_t seed, float* obs) const {
  auto& s = static_cast<TermsState&>(base);
  s.rng.seed(seed);
  s.step = 0;
  s.episode_return = 0;
  s.ended_by_term = false;
  std::fill(s.reward_sums.begin(), s.reward_sums.end(), 0.0);
  std::fill(s.value_sums.begin(), s.value_sums.end(), 0.0);
  for (auto& a : s.air_time) std::fill(a.begin(), a.end(), 0.0);
  for (auto& c : s.last_contact) std::fill(c.begin(), c.end(), 0);
  const auto& r = cfg_.reset();
  if (randomized_model_) randomize_model(s);
  const mjModel* m = model_of(s);
  mjData* d = s.data;
  mj_resetData(m, d);
  std::copy(default_qpos_.begin(), default_qpos_.end(), d->qpos);
  if (r.joint_pos_scale_min() != 1.0 || r.joint_pos_scale_max() != 1.0) {
    std::uniform_real_distribution<double> scale(r.joint_pos_scale_min(), r.joint_pos_scale_max());
    for (int j : scaled_joints_) {
      const int a = m->jnt_qposadr[j];
      const double q = default_qpos_[a] * scale(s.rng);
      d->qpos[a] = m->jnt_limited[j] ? std::clamp(q, m->jnt_range[2 * j], m->jnt_range[2 * j + 1]) : q;
    }
  }
  if (!clear_geoms_.empty() && root_free_qpos_ >= 0) {
    // Lift the root until the lowest of the geoms clears the floor (a scaled pose can reach below it).
    mj_kinematics(m, d);
    double lowest = INFINITY;
    for (int g : clear_geoms_) {
      const double radius = m->geom_type[g] == mjGEOM_SPHERE ? m->geom_size[3 * g] : m->geom_rbound[g];
      lowest = std::min(lowest, d->geom_xpos[3 * g + 2] - radius);
    }
    if (lowest < r.clearance()) d->qpos[root_free_qpos_ + 2] += r.clearance() - lowest;
  }
  std::uniform_real_distribution<double> qpos_noise(-r.qpos_noise(), r.qpos_noise());
  if (r.qpos_noise() > 0)
    for (int i = 0; i < m->nq; ++i) d->qpos[i] += qpos_noise(s.rng);
  std::normal_distribution<double> normal(0.0, 1.0);
  std::uniform_real_distribution<double> qvel_uniform(-r.qvel_noise(), r.qvel_noise());
  for (int i = 0; i < m->nv; ++i) {
    const double noise = r.qvel_noise() <= 0 ? 0.0
                         : r.qvel_uniform()  ? qvel_uniform(s.rng)
                                             : r.qvel_noise() * normal(s.rng);
    d->qvel[i] = default_qvel_[i] + noise;
  }
  if (r.root_vel_noise() > 0 && root_free_dof_ >= 0) {
    std::uniform_real_distribution<double> vel(-r.root_vel_noise(), r.root_vel_noise());
    for (int k = 0; k < 6; ++k) d->qvel[root_free_dof_ + k] += vel(s.rng);
  }
  mj_forward(m, d);
  sample_command(s);
  s.push_every_steps = r.push_interval_s() > 0 ? std::max(1, int(std::lround(r.push_interval_s() / agent_dt()))) : 0;
  std::fill(s.action.begin(), s.action.end(), 0.0);
  std::fill(s.last_action.begin(), s.last_action.end(), 0.0);
  s.last_qvel.assign(d->qvel, d->qvel + m->nv);
  s.start_x = d->xpos[3 * root_];
  write_obs(s, obs);
}

void TermsTask::apply_action(TermsState& s, mjData* d) const {
  const mjModel* m = model_of(s);
  const auto& a = cfg_.action();
  const Bound& b = *bound_;
  if (a.type() == "actuator") {
    for (size_t i = 0; i < b.targets.size(); ++i) {
      const int act = b.targets[i];
      const double u = std::clamp(a.scale() * s.action[i], -1.0, 1.0);
      if (m->actuator_ctrllimited[act]) {
        const double lo = m->actuator_ctrlrange[2 * act], hi = m->actuator_ctrlrange[2 * act + 1];
        d->ctrl[act] = 0.5 * (lo + hi) + 0.5 * (hi - lo) * u;
      } else {
        d->ctrl[act] = a.scale() * s.action[i];
      }
    }
    return;
  }
  // "position": the PD law on this physics step.
  for (size_t i = 0; i < b.targets.size(); ++i) {
    const int act = b.target_actuator[i];
    const double qd = d->qvel[b.target_dofs[i]];
    double tau = a.kp() * (s.targets[i] - d->qpos[b.target_qpos[i]]) - a.kd() * qd;
    if (a.torque_limit() > 0) tau = std::clamp(tau, -a.torque_limit(), a.torque_limit());
    if (std::abs(qd) > a.velocity_limit() && tau * qd > 0) tau = 0;
    const double gear = m->actuator_gear[6 * act] != 0 ? m->actuator_gear[6 * act] : 1.0;
    double u = tau / gear;
    if (m->actuator_ctrllimited[act])
      u = std::clamp(u, m->actuator_ctrlrange[2 * act], m->actuator_ctrlrange[2 * act + 1]);
    d->ctrl[act] = u;
  }
}

void TermsTask::update_quantities(TermsState& s) const {
  const mjModel* m = model_of(s);
  const mjData* d = s.data;
  double ang_w[3], lin_w[3], ang[3], lin[3], g[3];
  projected_gravity(m, d, root_, g);
  const double up_z = -g[2];
  body_velocity(m, d, root_, false, ang_w, lin_w);
  body_velocity(m, d, root_, true, ang, lin);
  double act_sq = 0, tau_sq = 0;
  for (double a : s.action) act_sq += a * a;
  for (int i = 0; i < m->nu; ++i) tau_sq += d->actuator_force[i] * d->actuator_force[i];
  const double values[] = {lin_w[0],
                           lin_w[1],
                           lin_w[2],
                           (d->xpos[3 * root_] - s.xpos_before[3 * root_]) / agent_dt(),
                           d->xpos[3 * root_ + 2],
                           up_z,
                           ang[0],
                           ang[1],
                           ang[2],
                           act_sq,
                           tau_sq,
                           s.command[0],
                           s.command[1],
                           s.command[2],
                           double(s.step),
                           s.step * agent_dt()};
  size_t k = 0;
  for (double v : values) s.quantities[k++] = v;
  for (int i = 0; i < m->nsensor; ++i) {
    if (info_.sensors[i].name.empty()) continue;
    for (int j = 0; j < m->sensor_dim[i]; ++j) s.quantities[k++] = d->sensordata[m->sensor_adr[i] + j];
  }
}

StepResult TermsTask::step(TaskState& base, const float* action, float* obs) const {
  auto& s = static_cast<TermsState&>(base);
  const mjModel* m = model_of(s);
  mjData* d = s.data;
  const auto& a = cfg_.action();
  for (size_t i = 0; i < s.action.size(); ++i) {
    // A NaN action (a diverged policy) means no action; std::clamp passes NaN through.
    s.action[i] = std::isnan(action[i]) ? 0.0 : std::clamp(double(action[i]), -1.0, 1.0);
    if (a.type() == "position") s.targets[i] = default_qpos_[bound_->target_qpos[i]] + a.scale() * s.action[i];
  }
  std::copy(d->xpos, d->xpos + 3 * m->nbody, s.xpos_before.begin());
  std::copy(d->qpos, d->qpos + m->nq, s.qpos_before.begin());
  if (bound_->com_before) mass_center(m, d, s.com_before.data());
  if (a.type() == "actuator") apply_action(s, d);
  for (int k = 0; k < cfg_.control_substeps(); ++k) {
    if (a.type() == "position") apply_action(s, d);
    mj_step(m, d);
    if (s.after_physics_step) s.after_physics_step();
  }
  // mj_step leaves cfrc_ext (and cacc, cfrc_int) as they were unless a sensor needs them;
  // Gymnasium's MuJoCo environments compute them once after the step's physics steps, as here.
  if (bound_->rne_post_constraint) mj_rnePostConstraint(m, d);
  ++s.step;
  StepResult r;
  bool finite = true;
  for (int i = 0; i < m->nq && finite; ++i) finite = std::isfinite(d->qpos[i]);
  for (int i = 0; i < m->nv && finite; ++i)
    finite = std::isfinite(d->qvel[i]) && std::abs(d->qvel[i]) <= cfg_.max_qvel();
  if (!finite) {
    // Diverged: the episode ends; the observation is zeros (nothing of the state is sane).
    s.ended_by_term = true;
    r.terminated = true;
    std::fill(obs, obs + spec_.obs_dim, 0.f);
    return r;
  }
  if (s.push_every_steps > 0 && root_free_dof_ >= 0 && s.step % s.push_every_steps == 0) {
    std::uniform_real_distribution<double> push(-cfg_.reset().push_max_vel(), cfg_.reset().push_max_vel());
    d->qvel[root_free_dof_] += push(s.rng);
    d->qvel[root_free_dof_ + 1] += push(s.rng);
  }
  const auto& c = cfg_.command();
  if (c.resample_prob() > 0 && std::uniform_real_distribution<double>(0, 1)(s.rng) < c.resample_prob())
    sample_command(s);
  if (c.heading()) s.command[2] = heading_yaw_rate(s);
  if (!s.parsers.empty()) update_quantities(s);
  const Ctx ctx{m, d, s, *this};
  double total = 0;
  for (const auto& b : bound_->rewards) {
    const double value = b.fn(ctx, b);
    const double v = b.cfg->weight() * value;
    s.value_sums[b.slot] += value;
    s.reward_sums[b.slot] += v;
    total += v;
  }
  if (cfg_.only_positive_rewards()) total = std::max(0.0, total);
  r.reward = float(total);
  for (const auto& t : bound_->terminations)
    if (t.fn(ctx, t)) r.terminated = true;
  if (r.terminated) {
    s.ended_by_term = true;
  } else if (s.step >= cfg_.max_episode_steps()) {
    r.truncated = true;
  }
  s.episode_return += r.reward;
  s.last_action = s.action;
  s.last_qvel.assign(d->qvel, d->qvel + m->nv);
  write_obs(s, obs);
  return r;
}

void TermsTask::write_obs(TermsState& s, float* obs) const {
  const Ctx ctx{model_of(s), s.data, s, *this};
  int at = 0;
  for (const auto& b : bound_->obs) {
    double* raw = s.obs_raw.data() + at;
    b.fn(ctx, b, raw);
    const auto& o = *b.cfg;
    std::uniform_real_distribution<double> noise(-o.noise(), o.noise());
    for (int i = 0; i < b.size; ++i) {
      double v = (raw[i] - o.offset()) * o.scale();
      if (o.noise() > 0) v += noise(s.rng);
      obs[at + i] = float(std::clamp(v, -o.clip(), o.clip()));
    }
    at += b.size;
  }
}

void TermsTask::episode_metrics(const TaskState& base, float* out) const {
  const auto& s = static_cast<const TermsState&>(base);
  out[0] = float(s.data->xpos[3 * root_] - s.start_x);
  out[1] = s.ended_by_term ? 1.f : 0.f;
  out[2] = float(s.step * agent_dt());
  const size_t n = s.reward_sums.size();
  const double steps = std::max(1, s.step);
  for (size_t i = 0; i < n; ++i) {
    out[3 + i] = float(s.reward_sums[i]);
    out[3 + n + i] = float(s.value_sums[i] / steps);
  }
}

std::unique_ptr<Task> make_terms_task(const config::TaskConfig& cfg) {
  return std::make_unique<TermsTask>(cfg.terms());
}

void TermsTask::view(const TaskState& base, const mjData* pose, int root, TaskView& out) const {
  const auto& s = static_cast<const TermsState&>(base);
  out.elevation = -20;
  const auto& c = cfg_.command();
  if (c.lin_vel_x_min() != 0 || c.lin_vel_x_max() != 0 || c.lin_vel_y_min() != 0 || c.lin_vel_y_max() != 0 ||
      c.yaw_rate_min() != 0 || c.yaw_rate_max() != 0)
    command_view(s.command.data(), pose, root, out);
}

}  // namespace farm::robots::terms
