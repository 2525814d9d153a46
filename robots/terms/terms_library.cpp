// The library of terms. Each term is one function; terms_catalogue.def lists it by name, with what
// its `names` select and the parameters it reads (checked by the loader, terms_check.cpp).
#include "terms/terms_library.h"

#include <muParser.h>
#include <mujoco/mujoco.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace farm::robots::terms {

namespace {

// The free joint of a body, or -1.
int free_joint(const mjModel* m, int body) {
  const int j = m->body_jntadr[body];
  return j >= 0 && m->jnt_type[j] == mjJNT_FREE ? j : -1;
}

bool in(const std::vector<int>& v, int x) { return std::find(v.begin(), v.end(), x) != v.end(); }

// Whether contact `con` is between the group and a geom it counts against; `group2` says whether
// the group's geom is the contact's geom2.
bool counts(const mjContact& con, const std::vector<int>& geoms, const std::vector<int>& other, bool* group2) {
  const bool g1 = in(geoms, con.geom1), g2 = in(geoms, con.geom2);
  if (g1 == g2) return false;  // neither, or both (the group touching itself)
  if (!other.empty() && !in(other, g1 ? con.geom2 : con.geom1)) return false;
  *group2 = g2;
  return true;
}

}  // namespace

void body_rotation(const mjModel* m, const mjData* d, int body, double R[9]) {
  const int j = free_joint(m, body);
  if (j < 0) {
    mju_copy(R, d->xmat + 9 * body, 9);
    return;
  }
  mjtNum q[4];
  mju_copy4(q, d->qpos + m->jnt_qposadr[j] + 3);
  mju_normalize4(q);
  mju_quat2Mat(R, q);
}

void body_velocity(const mjModel* m, const mjData* d, int body, bool local, double ang[3], double lin[3]) {
  const int j = free_joint(m, body);
  if (j < 0) {
    mjtNum res[6];
    mj_objectVelocity(m, d, mjOBJ_BODY, body, res, local ? 1 : 0);
    for (int i = 0; i < 3; ++i) {
      ang[i] = res[i];
      lin[i] = res[3 + i];
    }
    return;
  }
  // A free joint's qvel: the body origin's linear velocity in the world frame, then its angular
  // velocity in the body's frame.
  const mjtNum* v = d->qvel + m->jnt_dofadr[j];
  mjtNum R[9];
  body_rotation(m, d, body, R);
  if (local) {
    mju_mulMatTVec(lin, R, v, 3, 3);
    mju_copy3(ang, v + 3);
  } else {
    mju_copy3(lin, v);
    mju_mulMatVec(ang, R, v + 3, 3, 3);
  }
}

double body_height(const mjModel* m, const mjData* d, int body) {
  const int j = free_joint(m, body);
  return j >= 0 ? d->qpos[m->jnt_qposadr[j] + 2] : d->xpos[3 * body + 2];
}

void projected_gravity(const mjModel* m, const mjData* d, int body, double out[3]) {
  // R^T (0, 0, -1): minus the third row of the body's rotation matrix.
  mjtNum R[9];
  body_rotation(m, d, body, R);
  out[0] = -R[6];
  out[1] = -R[7];
  out[2] = -R[8];
}

bool touches(const mjData* d, const std::vector<int>& geoms, const std::vector<int>& other) {
  bool g2;
  for (int c = 0; c < d->ncon; ++c)
    if (counts(d->contact[c], geoms, other, &g2)) return true;
  return false;
}

void contact_force(const mjModel* m, const mjData* d, const std::vector<int>& geoms, const std::vector<int>& other,
                   double out[3]) {
  out[0] = out[1] = out[2] = 0;
  for (int c = 0; c < d->ncon; ++c) {
    const mjContact& con = d->contact[c];
    bool g2 = false;
    if (!counts(con, geoms, other, &g2)) continue;
    mjtNum f6[6];
    mj_contactForce(m, d, c, f6);
    // f6 is in the contact frame (rows of con.frame); to the world: frame^T f. The force acts on
    // geom2 along the normal: on geom1's body it is the opposite.
    double w[3] = {0, 0, 0};
    for (int i = 0; i < 3; ++i)
      for (int k = 0; k < 3; ++k) w[i] += con.frame[3 * k + i] * f6[k];
    const double sign = g2 ? 1.0 : -1.0;
    for (int i = 0; i < 3; ++i) out[i] += sign * w[i];
  }
}

void mass_center(const mjModel* m, const mjData* d, double out[3]) {
  double mass = 0;
  out[0] = out[1] = out[2] = 0;
  for (int b = 0; b < m->nbody; ++b) {
    mass += m->body_mass[b];
    for (int k = 0; k < 3; ++k) out[k] += m->body_mass[b] * d->xipos[3 * b + k];
  }
  for (int k = 0; k < 3; ++k) out[k] /= std::max(mass, mjMINVAL);
}

namespace {

// Contact forces above this (N) count as a touch (legged_gym's contact threshold).
constexpr double kTouchForce = 1.0;

double norm3(const double f[3]) { return std::sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]); }

bool local(const std::string& frame) { return frame == "local"; }

// Observation terms: raw values; the task applies offset, scale, noise and clip.

void obs_joint_pos(const Ctx& c, const ObsBinding& b, double* out) {
  for (size_t i = 0; i < b.ids.size(); ++i) out[i] = c.d->qpos[c.m->jnt_qposadr[b.ids[i]]];
}
void obs_joint_pos_rel(const Ctx& c, const ObsBinding& b, double* out) {
  for (size_t i = 0; i < b.ids.size(); ++i) {
    const int a = c.m->jnt_qposadr[b.ids[i]];
    out[i] = c.d->qpos[a] - c.task.default_qpos()[a];
  }
}
void obs_joint_vel(const Ctx& c, const ObsBinding& b, double* out) {
  for (size_t i = 0; i < b.ids.size(); ++i) out[i] = c.d->qvel[c.m->jnt_dofadr[b.ids[i]]];
}
void obs_qpos(const Ctx& c, const ObsBinding& b, double* out) {
  for (int i = b.cfg->skip(); i < c.m->nq; ++i) out[i - b.cfg->skip()] = c.d->qpos[i];
}
void obs_qvel(const Ctx& c, const ObsBinding& b, double* out) {
  for (int i = b.cfg->skip(); i < c.m->nv; ++i) out[i - b.cfg->skip()] = c.d->qvel[i];
}
void obs_body_pos(const Ctx& c, const ObsBinding& b, double* out) {
  for (size_t i = 0; i < b.ids.size(); ++i)
    for (int k = 0; k < 3; ++k) out[3 * i + k] = c.d->xpos[3 * b.ids[i] + k];
}
void obs_body_height(const Ctx& c, const ObsBinding& b, double* out) {
  for (size_t i = 0; i < b.ids.size(); ++i) out[i] = body_height(c.m, c.d, b.ids[i]);
}
void obs_body_quat(const Ctx& c, const ObsBinding& b, double* out) {
  for (size_t i = 0; i < b.ids.size(); ++i)
    for (int k = 0; k < 4; ++k) out[4 * i + k] = c.d->xquat[4 * b.ids[i] + k];
}
void obs_body_lin_vel(const Ctx& c, const ObsBinding& b, double* out) {
  double ang[3];
  for (size_t i = 0; i < b.ids.size(); ++i) body_velocity(c.m, c.d, b.ids[i], local(b.cfg->frame()), ang, out + 3 * i);
}
void obs_body_ang_vel(const Ctx& c, const ObsBinding& b, double* out) {
  double lin[3];
  for (size_t i = 0; i < b.ids.size(); ++i) body_velocity(c.m, c.d, b.ids[i], local(b.cfg->frame()), out + 3 * i, lin);
}
void obs_projected_gravity(const Ctx& c, const ObsBinding& b, double* out) {
  for (size_t i = 0; i < b.ids.size(); ++i) projected_gravity(c.m, c.d, b.ids[i], out + 3 * i);
}
void obs_sensor(const Ctx& c, const ObsBinding& b, double* out) {
  int k = 0;
  for (int s : b.ids)
    for (int i = 0; i < c.m->sensor_dim[s]; ++i) out[k++] = c.d->sensordata[c.m->sensor_adr[s] + i];
}
void obs_last_action(const Ctx& c, const ObsBinding&, double* out) {
  std::copy(c.s.last_action.begin(), c.s.last_action.end(), out);
}
void obs_command(const Ctx& c, const ObsBinding&, double* out) {
  std::copy(c.s.command.begin(), c.s.command.end(), out);
}
void obs_command_lin_vel(const Ctx& c, const ObsBinding&, double* out) {
  out[0] = c.s.command[0];
  out[1] = c.s.command[1];
}
void obs_command_yaw_rate(const Ctx& c, const ObsBinding&, double* out) { out[0] = c.s.command[2]; }
void obs_contact(const Ctx& c, const ObsBinding& b, double* out) {
  const auto& k = b.contacts;
  for (size_t i = 0; i < k.geoms.size(); ++i) out[i] = touches(c.d, k.geoms[i], k.other) ? 1.0 : 0.0;
}

// MuJoCo's per-body arrays as they stand after the step (Gymnasium's Humanoid-v4 observes them
// whole): cinert, each body's inertia and mass (10), and cvel, its velocity (angular, linear; 6),
// both taken about the centre of mass of the body's tree with world axes, from the kinematics of
// the step's last forward pass; cfrc_ext, the contact and applied forces on it (torque, force; 6),
// from mj_rnePostConstraint after the step (after a reset, what mj_forward left: zeros unless a
// sensor needs them, as in Gymnasium).
void obs_cinert(const Ctx& c, const ObsBinding& b, double* out) {
  for (size_t i = 0; i < b.ids.size(); ++i) std::copy_n(c.d->cinert + 10 * b.ids[i], 10, out + 10 * i);
}
void obs_cvel(const Ctx& c, const ObsBinding& b, double* out) {
  for (size_t i = 0; i < b.ids.size(); ++i) std::copy_n(c.d->cvel + 6 * b.ids[i], 6, out + 6 * i);
}
void obs_cfrc_ext(const Ctx& c, const ObsBinding& b, double* out) {
  for (size_t i = 0; i < b.ids.size(); ++i) std::copy_n(c.d->cfrc_ext + 6 * b.ids[i], 6, out + 6 * i);
}
// The actuators' generalized forces, per dof, less `skip` leading dofs (a free root's six).
void obs_qfrc_actuator(const Ctx& c, const ObsBinding& b, double* out) {
  for (int i = b.cfg->skip(); i < c.m->nv; ++i) out[i - b.cfg->skip()] = c.d->qfrc_actuator[i];
}
void obs_com_pos(const Ctx& c, const ObsBinding&, double* out) { mass_center(c.m, c.d, out); }
// The centre of mass's velocity (world): the mass-weighted mean of each body's centre-of-mass
// velocity, MuJoCo's subtree_linvel of the world body.
void obs_com_vel(const Ctx& c, const ObsBinding&, double* out) {
  double mass = 0, v[6];
  out[0] = out[1] = out[2] = 0;
  for (int body = 1; body < c.m->nbody; ++body) {
    mj_objectVelocity(c.m, c.d, mjOBJ_BODY, body, v, 0);
    mass += c.m->body_mass[body];
    for (int k = 0; k < 3; ++k) out[k] += c.m->body_mass[body] * v[3 + k];
  }
  for (int k = 0; k < 3; ++k) out[k] /= std::max(mass, mjMINVAL);
}

// Reward terms: the value before the weight.

double rew_alive(const Ctx&, const RewardBinding&) { return 1.0; }
double rew_forward_progress(const Ctx& c, const RewardBinding& b) {
  const int ax = b.cfg->axis(), body = b.ids[0];
  return (c.d->xpos[3 * body + ax] - c.s.xpos_before[3 * body + ax]) / c.task.agent_dt();
}
// The centre of mass's displacement along `axis` over the step, per second: Gymnasium's
// x_velocity of Humanoid (mass_center after minus before, over dt).
double rew_com_progress(const Ctx& c, const RewardBinding& b) {
  double com[3];
  mass_center(c.m, c.d, com);
  const int ax = b.cfg->axis();
  return (com[ax] - c.s.com_before[ax]) / c.task.agent_dt();
}
// A slide joint's displacement over the step, per second: Gymnasium's x_velocity of its planar
// models (HalfCheetah, Hopper, Walker2d: qpos[0] after minus before, over dt). The first joint named.
double rew_joint_progress(const Ctx& c, const RewardBinding& b) {
  const int a = c.m->jnt_qposadr[b.ids[0]];
  return (c.d->qpos[a] - c.s.qpos_before[a]) / c.task.agent_dt();
}
double rew_body_velocity(const Ctx& c, const RewardBinding& b) {
  double ang[3], lin[3];
  body_velocity(c.m, c.d, b.ids[0], local(b.cfg->frame()), ang, lin);
  return lin[b.cfg->axis()];
}
double rew_ctrl_cost(const Ctx& c, const RewardBinding&) {
  double s = 0;
  for (double a : c.s.action) s += a * a;
  return s;
}
double rew_torque_cost(const Ctx& c, const RewardBinding&) {
  double s = 0;
  for (int i = 0; i < c.m->nu; ++i) s += c.d->actuator_force[i] * c.d->actuator_force[i];
  return s;
}
double rew_action_rate(const Ctx& c, const RewardBinding&) {
  double s = 0;
  for (size_t i = 0; i < c.s.action.size(); ++i) s += std::pow(c.s.action[i] - c.s.last_action[i], 2);
  return s;
}
double rew_upright(const Ctx& c, const RewardBinding& b) {
  double g[3];
  projected_gravity(c.m, c.d, b.ids[0], g);
  return -g[2];
}
double rew_height(const Ctx& c, const RewardBinding& b) {
  return std::pow(body_height(c.m, c.d, b.ids[0]) - b.cfg->target(), 2);
}
double rew_lin_vel_tracking(const Ctx& c, const RewardBinding& b) {
  double ang[3], lin[3];
  body_velocity(c.m, c.d, b.ids[0], true, ang, lin);
  const double e = std::pow(c.s.command[0] - lin[0], 2) + std::pow(c.s.command[1] - lin[1], 2);
  return std::exp(-e / b.cfg->sigma());
}
double rew_ang_vel_tracking(const Ctx& c, const RewardBinding& b) {
  double ang[3], lin[3];
  body_velocity(c.m, c.d, b.ids[0], true, ang, lin);
  return std::exp(-std::pow(c.s.command[2] - ang[2], 2) / b.cfg->sigma());
}
double rew_lin_vel_z(const Ctx& c, const RewardBinding& b) {
  double ang[3], lin[3];
  body_velocity(c.m, c.d, b.ids[0], true, ang, lin);
  return lin[2] * lin[2];
}
double rew_ang_vel_xy(const Ctx& c, const RewardBinding& b) {
  double ang[3], lin[3];
  body_velocity(c.m, c.d, b.ids[0], true, ang, lin);
  return ang[0] * ang[0] + ang[1] * ang[1];
}
double rew_orientation(const Ctx& c, const RewardBinding& b) {
  double g[3];
  projected_gravity(c.m, c.d, b.ids[0], g);
  return g[0] * g[0] + g[1] * g[1];
}
double rew_joint_limits(const Ctx& c, const RewardBinding& b) {
  // legged_gym's dof_pos_limits: how far each joint is outside the middle `target` share of its range.
  double s = 0;
  for (int j : b.ids) {
    const double lo = c.m->jnt_range[2 * j], hi = c.m->jnt_range[2 * j + 1];
    const double mid = 0.5 * (lo + hi), half = 0.5 * (hi - lo) * b.cfg->target();
    const double q = c.d->qpos[c.m->jnt_qposadr[j]];
    s += std::max(0.0, (mid - half) - q) + std::max(0.0, q - (mid + half));
  }
  return s;
}
double rew_joint_vel_cost(const Ctx& c, const RewardBinding& b) {
  double s = 0;
  for (int j : b.ids) s += std::pow(c.d->qvel[c.m->jnt_dofadr[j]], 2);
  return s;
}
double rew_joint_acc(const Ctx& c, const RewardBinding& b) {
  double s = 0;
  const double dt = c.task.agent_dt();
  for (int j : b.ids) {
    const int a = c.m->jnt_dofadr[j];
    s += std::pow((c.s.last_qvel[a] - c.d->qvel[a]) / dt, 2);
  }
  return s;
}
double rew_contact_forces(const Ctx& c, const RewardBinding& b) {
  double s = 0, f[3];
  const auto& k = b.contacts;
  for (const auto& geoms : k.geoms) {
    contact_force(c.m, c.d, geoms, k.other, f);
    s += std::max(0.0, norm3(f) - b.cfg->threshold());
  }
  return s;
}
// How many items are in contact: with a net contact force above `threshold` (N), or with any
// contact at all when it is 0.
double rew_collision(const Ctx& c, const RewardBinding& b) {
  double n = 0, f[3];
  const auto& k = b.contacts;
  for (const auto& geoms : k.geoms) {
    if (b.cfg->threshold() <= 0) {
      n += touches(c.d, geoms, k.other) ? 1 : 0;
    } else {
      contact_force(c.m, c.d, geoms, k.other, f);
      n += norm3(f) > b.cfg->threshold() ? 1 : 0;
    }
  }
  return n;
}
double rew_feet_air_time(const Ctx& c, const RewardBinding& b) {
  // legged_gym's feet_air_time: on the step a foot lands, the time it spent in the air beyond
  // `threshold`; only under a moving command. A contact counts on its step and the one after.
  auto& air = c.s.air_time[b.slot];
  auto& last = c.s.last_contact[b.slot];
  const double dt = c.task.agent_dt();
  double r = 0, f[3];
  for (size_t i = 0; i < b.contacts.geoms.size(); ++i) {
    contact_force(c.m, c.d, b.contacts.geoms[i], b.contacts.other, f);
    const bool contact = f[2] > kTouchForce;
    const bool filt = contact || last[i];
    const bool first = air[i] > 0 && filt;
    air[i] += dt;
    r += (air[i] - b.cfg->threshold()) * (first ? 1 : 0);
    if (filt) air[i] = 0;
    last[i] = contact;
  }
  return std::hypot(c.s.command[0], c.s.command[1]) > 0.1 ? r : 0.0;
}
double rew_expression(const Ctx& c, const RewardBinding& b) { return c.s.parsers[b.slot]->Eval(); }

// Termination terms.

bool end_body_contact(const Ctx& c, const TerminationBinding& b) {
  for (const auto& geoms : b.contacts.geoms)
    if (touches(c.d, geoms, b.contacts.other)) return true;
  return false;
}
bool end_height(const Ctx& c, const TerminationBinding& b) {
  const double z = body_height(c.m, c.d, b.ids[0]);
  return !(z >= b.cfg->min() && z <= b.cfg->max());
}
bool end_orientation(const Ctx& c, const TerminationBinding& b) {
  double g[3];
  projected_gravity(c.m, c.d, b.ids[0], g);
  return -g[2] < b.cfg->min();
}
// A named joint's position outside [min, max] (Hopper's and Walker2d's healthy_angle_range on the
// rooty hinge, Walker2d's healthy_z_range on the rootz slide).
bool end_joint_pos(const Ctx& c, const TerminationBinding& b) {
  for (int j : b.ids) {
    const double q = c.d->qpos[c.m->jnt_qposadr[j]];
    if (!(q >= b.cfg->min() && q <= b.cfg->max())) return true;
  }
  return false;
}
// Gymnasium's state_vector() (qpos, then qvel) from entry `skip` on: any entry outside [min, max]
// (Hopper's healthy_state_range over state[2:]).
bool end_state(const Ctx& c, const TerminationBinding& b) {
  const int nq = c.m->nq;
  for (int i = b.cfg->skip(); i < nq + c.m->nv; ++i) {
    const double v = i < nq ? c.d->qpos[i] : c.d->qvel[i - nq];
    if (!(v >= b.cfg->min() && v <= b.cfg->max())) return true;
  }
  return false;
}
bool end_non_finite(const Ctx& c, const TerminationBinding& b) {
  for (int i = 0; i < c.m->nv; ++i)
    if (!std::isfinite(c.d->qvel[i]) || std::abs(c.d->qvel[i]) > b.cfg->max()) return true;
  for (int i = 0; i < c.m->nq; ++i)
    if (!std::isfinite(c.d->qpos[i])) return true;
  return false;
}

template <typename Fn>
struct Entry {
  const char* name;
  Fn fn;
};
const Entry<ObsFn> kObs[] = {
#define OBS(name, names, size, params) {#name, &obs_##name},
#include "terms/terms_catalogue.def"
#undef OBS
};
const Entry<RewardFn> kRewards[] = {
#define REWARD(name, names, params) {#name, &rew_##name},
#include "terms/terms_catalogue.def"
#undef REWARD
};
const Entry<TerminationFn> kTerminations[] = {
#define TERMINATION(name, names, params) {#name, &end_##name},
#include "terms/terms_catalogue.def"
#undef TERMINATION
};

template <typename Fn, size_t N>
Fn lookup(const Entry<Fn> (&table)[N], const std::string& name, const char* what) {
  for (const auto& e : table)
    if (name == e.name) return e.fn;
  throw std::invalid_argument(std::string("unknown ") + what + " term '" + name + "'");
}

Names names_of(const std::vector<TermInfo>& list, const std::string& name) {
  for (const auto& t : list)
    if (name == t.name) return t.names;
  return Names::None;
}

// A term's items: what `names` selects, or for a contact term its bodies or geoms, bound to geoms.
template <typename Entry>
std::vector<int> items(Names kind, const Entry& e, const ModelInfo& info, const mjModel* m, int root,
                       ContactItems& contacts) {
  if (kind == Names::None) return {};
  if (kind != Names::Contacts && kind != Names::ContactsRequired) return select(kind, e.names(), info, root);
  bool by_geom = false;
  std::vector<int> ids = contact_items(kind, e.names(), e.geoms(), info, root, &by_geom);
  for (int id : ids) {
    std::vector<int> geoms;
    if (by_geom) {
      geoms.push_back(id);
    } else {
      for (int g = 0; g < m->ngeom; ++g)
        if (m->geom_bodyid[g] == id) geoms.push_back(g);
    }
    contacts.geoms.push_back(std::move(geoms));
  }
  if (!e.other().empty()) contacts.other = select(Names::Geoms, e.other(), info, root);
  return ids;
}

}  // namespace

void bind(const config::TermsConfig& cfg, const ModelInfo& info, const mjModel* m, int root, Bound& out) {
  out.targets = action_targets(cfg, info);
  const int act_dim = int(out.targets.size());
  if (cfg.action().type() == "position") {
    for (int j : out.targets) {
      out.target_dofs.push_back(m->jnt_dofadr[j]);
      out.target_qpos.push_back(m->jnt_qposadr[j]);
      int act = -1;
      for (int a = 0; a < m->nu; ++a)
        if (m->actuator_trntype[a] == mjTRN_JOINT && m->actuator_trnid[2 * a] == j) act = a;
      if (act < 0) throw std::invalid_argument("task.terms.action: joint " + info.joints[j].name + " has no actuator");
      out.target_actuator.push_back(act);
    }
  }
  for (const auto& o : cfg.observation()) {
    ObsBinding b{&o, lookup(kObs, o.term(), "observation"), {}, observation_size(o, info, root, act_dim), {}};
    b.ids = items(names_of(observation_terms(), o.term()), o, info, m, root, b.contacts);
    out.obs.push_back(std::move(b));
    if (o.term() == "cfrc_ext") out.rne_post_constraint = true;
  }
  for (int i = 0; i < cfg.reward_size(); ++i) {
    const auto& r = cfg.reward(i);
    RewardBinding b{&r, lookup(kRewards, r.term(), "reward"), {}, i, {}};
    b.ids = items(names_of(reward_terms(), r.term()), r, info, m, root, b.contacts);
    out.rewards.push_back(std::move(b));
    if (r.term() == "com_progress") out.com_before = true;
  }
  for (const auto& t : cfg.termination()) {
    TerminationBinding b{&t, lookup(kTerminations, t.term(), "termination"), {}, {}};
    b.ids = items(names_of(termination_terms(), t.term()), t, info, m, root, b.contacts);
    out.terminations.push_back(std::move(b));
  }
}

}  // namespace farm::robots::terms
