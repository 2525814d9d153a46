#include "quadruped/legged.h"

#include <mujoco/mujoco.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace farm::robots::legged {

int property_size(Property p) {
  switch (p) {
    case Property::kBodyHeight:
    case Property::kJointPos:
    case Property::kJointVel:
      return 1;
    case Property::kBodyLinVelLocal:
    case Property::kBodyAngVelLocal:
    case Property::kProjectedGravity:
      return 3;
    case Property::kCustom:
      return 0;
  }
  return 0;
}

int ObsSpec::add(ObsItem item) {
  if (item.property != Property::kCustom) {
    if (item.ids.empty()) throw std::invalid_argument("observation item '" + item.label + "' names no body or joint");
    item.size = property_size(item.property) * int(item.ids.size());
  } else if (item.size <= 0 || !(item.low < item.high)) {
    throw std::invalid_argument("custom observation slot '" + item.label + "' needs size > 0 and low < high");
  }
  if (!item.offset.empty() && int(item.offset.size()) != item.size)
    throw std::invalid_argument("observation item '" + item.label + "': offset has " +
                                std::to_string(item.offset.size()) + " values, the item " + std::to_string(item.size));
  item.start = dim_;
  dim_ += item.size;
  items_.push_back(std::move(item));
  return items_.back().start;
}

const ObsItem& ObsSpec::item(const std::string& label) const {
  for (const auto& it : items_)
    if (it.label == label) return it;
  throw std::out_of_range("no observation item '" + label + "'");
}

namespace {

int free_joint_of(const mjModel* m, int body) {
  const int j = m->body_jntadr[body];
  return (j >= 0 && m->jnt_type[j] == mjJNT_FREE) ? j : -1;
}

// Rotation matrix (row-major, body -> world) of a body: from the free joint's quaternion when it
// has one (current after mj_step), else from xmat (from the last forward pass).
void body_rotation(const mjModel* m, const mjData* d, int body, mjtNum R[9]) {
  const int j = free_joint_of(m, body);
  if (j >= 0) {
    mjtNum q[4];
    mju_copy(q, d->qpos + m->jnt_qposadr[j] + 3, 4);
    mju_normalize4(q);
    mju_quat2Mat(R, q);
  } else {
    mju_copy(R, d->xmat + 9 * body, 9);
  }
}

void require_joint(const mjModel* m, int id) {
  if (id < 0 || id >= m->njnt || (m->jnt_type[id] != mjJNT_HINGE && m->jnt_type[id] != mjJNT_SLIDE))
    throw std::invalid_argument("joint property of joint " + std::to_string(id) + ": not a hinge or slide joint");
}

}  // namespace

void read_property(const mjModel* m, const mjData* d, Property p, int id, double* out) {
  switch (p) {
    case Property::kBodyHeight: {
      const int j = free_joint_of(m, id);
      out[0] = j >= 0 ? d->qpos[m->jnt_qposadr[j] + 2] : d->xpos[3 * id + 2];
      return;
    }
    case Property::kBodyLinVelLocal:
    case Property::kBodyAngVelLocal: {
      const int j = free_joint_of(m, id);
      if (j >= 0) {
        const mjtNum* v = d->qvel + m->jnt_dofadr[j];
        if (p == Property::kBodyAngVelLocal) {
          mju_copy3(out, v + 3);  // MuJoCo keeps a free joint's angular velocity in the local frame
        } else {
          mjtNum R[9];
          body_rotation(m, d, id, R);
          mju_mulMatTVec(out, R, v, 3, 3);
        }
      } else {
        mjtNum v6[6];
        mj_objectVelocity(m, d, mjOBJ_BODY, id, v6, 1);
        mju_copy3(out, p == Property::kBodyAngVelLocal ? v6 : v6 + 3);
      }
      return;
    }
    case Property::kProjectedGravity: {
      mjtNum R[9];
      body_rotation(m, d, id, R);
      const mjtNum g[3] = {0, 0, -1};
      mju_mulMatTVec(out, R, g, 3, 3);
      return;
    }
    case Property::kJointPos:
      require_joint(m, id);
      out[0] = d->qpos[m->jnt_qposadr[id]];
      return;
    case Property::kJointVel:
      require_joint(m, id);
      out[0] = d->qvel[m->jnt_dofadr[id]];
      return;
    case Property::kCustom:
      break;
  }
  throw std::invalid_argument("read_property: a custom slot is filled by the task, not read from the model");
}

void write_property(const mjModel* m, mjData* d, Property p, int id, const double* value) {
  switch (p) {
    case Property::kJointPos:
      require_joint(m, id);
      d->qpos[m->jnt_qposadr[id]] = value[0];
      return;
    case Property::kJointVel:
      require_joint(m, id);
      d->qvel[m->jnt_dofadr[id]] = value[0];
      return;
    case Property::kBodyHeight:
    case Property::kBodyLinVelLocal: {
      const int j = free_joint_of(m, id);
      if (j < 0) break;
      if (p == Property::kBodyHeight) {
        d->qpos[m->jnt_qposadr[j] + 2] = value[0];
      } else {
        mjtNum R[9];
        body_rotation(m, d, id, R);
        mju_mulMatVec(d->qvel + m->jnt_dofadr[j], R, value, 3, 3);
      }
      return;
    }
    case Property::kBodyAngVelLocal: {
      const int j = free_joint_of(m, id);
      if (j < 0) break;
      mju_copy3(d->qvel + m->jnt_dofadr[j] + 3, value);
      return;
    }
    default:
      break;
  }
  throw std::invalid_argument("write_property: property cannot be written for body/joint " + std::to_string(id));
}

void build_observation(const mjModel* m, const mjData* d, const ObsSpec& spec,
                       const std::vector<std::vector<double>>& custom, double noise_level, std::mt19937_64& rng,
                       float* obs) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  size_t next_custom = 0;
  double buf[3];
  for (const auto& it : spec.items()) {
    float* o = obs + it.start;
    if (it.property == Property::kCustom) {
      if (next_custom >= custom.size() || int(custom[next_custom].size()) != it.size)
        throw std::invalid_argument("custom observation slot '" + it.label + "' was not filled with " +
                                    std::to_string(it.size) + " values");
      const auto& v = custom[next_custom++];
      for (int k = 0; k < it.size; ++k) {
        double x = 2.0 * (v[k] - it.low) / (it.high - it.low) - 1.0;
        if (noise_level > 0 && it.noise > 0) x += it.noise * noise_level * u(rng);
        o[k] = float(x);
      }
      continue;
    }
    const int ps = property_size(it.property);
    for (size_t b = 0; b < it.ids.size(); ++b) {
      read_property(m, d, it.property, it.ids[b], buf);
      for (int k = 0; k < ps; ++k) {
        const int i = int(b) * ps + k;
        double x = (buf[k] - (it.offset.empty() ? 0.0 : it.offset[i])) * it.scale;
        if (noise_level > 0 && it.noise > 0) x += it.noise * it.scale * noise_level * u(rng);
        o[i] = float(x);
      }
    }
  }
}

CollisionGroup make_group(const mjModel* m, const std::string& name, const std::vector<std::string>& geom_names) {
  CollisionGroup g{name, {}};
  for (const auto& n : geom_names) g.geoms.push_back(geom_id(m, n));
  return g;
}

namespace {
bool member(const CollisionGroup& g, int geom) {
  return std::find(g.geoms.begin(), g.geoms.end(), geom) != g.geoms.end();
}
}  // namespace

bool touching(const mjModel*, const mjData* d, const CollisionGroup& a, const CollisionGroup& b) {
  for (int i = 0; i < d->ncon; ++i) {
    const mjContact& c = d->contact[i];
    if ((member(a, c.geom1) && member(b, c.geom2)) || (member(a, c.geom2) && member(b, c.geom1))) return true;
  }
  return false;
}

int count_touching(const mjModel*, const mjData* d, const CollisionGroup& a, const CollisionGroup& b) {
  int n = 0;
  for (int g : a.geoms) {
    for (int i = 0; i < d->ncon; ++i) {
      const mjContact& c = d->contact[i];
      if ((c.geom1 == g && member(b, c.geom2)) || (c.geom2 == g && member(b, c.geom1))) {
        ++n;
        break;
      }
    }
  }
  return n;
}

void net_contact_forces(const mjModel* m, const mjData* d, const CollisionGroup& g, std::vector<double>& out) {
  out.assign(3 * g.geoms.size(), 0.0);
  for (int i = 0; i < d->ncon; ++i) {
    const mjContact& c = d->contact[i];
    int k1 = -1, k2 = -1;
    for (size_t k = 0; k < g.geoms.size(); ++k) {
      if (g.geoms[k] == c.geom1) k1 = int(k);
      if (g.geoms[k] == c.geom2) k2 = int(k);
    }
    if (k1 < 0 && k2 < 0) continue;
    mjtNum f6[6], fw[3];
    mj_contactForce(m, d, i, f6);
    // The contact frame's rows are its axes; the normal points from geom1 to geom2 and the force
    // is the one geom1 exerts on geom2.
    mju_mulMatTVec(fw, c.frame, f6, 3, 3);
    for (int k = 0; k < 3; ++k) {
      if (k2 >= 0) out[3 * k2 + k] += fw[k];
      if (k1 >= 0) out[3 * k1 + k] -= fw[k];
    }
  }
}

void control_steps(const mjModel* m, mjData* d, int steps, const std::function<void(mjData*)>& controller,
                   const ControlHooks& hooks) {
  for (int k = 0; k < steps; ++k) {
    controller(d);
    if (hooks.before) hooks.before(d);
    mj_step(m, d);
    if (hooks.after) hooks.after(d);
  }
}

namespace {
int id_of(const mjModel* m, mjtObj type, const char* what, const std::string& name) {
  const int id = mj_name2id(m, type, name.c_str());
  if (id < 0) throw std::invalid_argument(std::string("the model has no ") + what + " named '" + name + "'");
  return id;
}
}  // namespace

int body_id(const mjModel* m, const std::string& name) { return id_of(m, mjOBJ_BODY, "body", name); }
int joint_id(const mjModel* m, const std::string& name) { return id_of(m, mjOBJ_JOINT, "joint", name); }
int geom_id(const mjModel* m, const std::string& name) { return id_of(m, mjOBJ_GEOM, "geom", name); }

}  // namespace farm::robots::legged
