#include "mobile/mobile_task.h"

#include <mujoco/mujoco.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <sstream>
#include <stdexcept>

#include "embedded_mjcf.h"
#include "mobile/kinematics.h"
#include "mobile/mobile_spec.h"

namespace farm::robots::mobile {

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr int kWorldGroup = 1;  // walls and obstacles: what the lidar sees
constexpr double kWallHalfThickness = 0.05;
constexpr double kObstacleLift = 1e-3;  // obstacles float 1 mm up: no contacts with the floor

double wrap_angle(double a) {
  a = std::fmod(a + kPi, 2 * kPi);
  if (a < 0) a += 2 * kPi;
  return a - kPi;
}

struct VfsDeleter {
  void operator()(mjVFS* v) const {
    mj_deleteVFS(v);
    delete v;
  }
};

// Compiles MJCF text through MuJoCo's VFS under `name`.
mjModel* load_xml_text(const std::string& name, const std::string& text) {
  std::unique_ptr<mjVFS, VfsDeleter> vfs(new mjVFS);
  mj_defaultVFS(vfs.get());
  if (mj_makeEmptyFileVFS(vfs.get(), name.c_str(), int(text.size())) != 0) {
    throw std::runtime_error("MJCF '" + name + "': could not add it to MuJoCo's VFS");
  }
  const int index = mj_findFileVFS(vfs.get(), name.c_str());
  std::memcpy(vfs->filedata[index], text.data(), text.size());
  char err[1000] = "";
  mjModel* m = mj_loadXML(name.c_str(), vfs.get(), err, sizeof err);
  if (!m) throw std::runtime_error("MJCF '" + name + "': " + (err[0] ? err : "load failed"));
  return m;
}

std::string embedded_text(const std::string& path) {
  for (const auto& f : embedded_mjcf()) {
    if (path == f.path) return f.text;
  }
  throw std::runtime_error("MJCF '" + path + "' is not embedded");
}

// Walls around the arena and one mocap body per obstacle slot, parked outside the walls.
std::string scene_xml(const config::MobileSceneConfig& c, const std::vector<ObstacleSlot>& slots) {
  std::ostringstream x;
  x.precision(9);
  const double h = c.arena_half_size(), t = kWallHalfThickness, hz = c.wall_height() / 2;
  const char* attrs = R"( contype="1" conaffinity="2" group="1" rgba="0.5 0.4 0.3 1"/>)";
  x << "<geom name=\"wall_east\" type=\"box\" pos=\"" << h + t << " 0 " << hz << "\" size=\"" << t << ' ' << h + 2 * t
    << ' ' << hz << '"' << attrs << '\n';
  x << "<geom name=\"wall_west\" type=\"box\" pos=\"" << -(h + t) << " 0 " << hz << "\" size=\"" << t << ' '
    << h + 2 * t << ' ' << hz << '"' << attrs << '\n';
  x << "<geom name=\"wall_north\" type=\"box\" pos=\"0 " << h + t << ' ' << hz << "\" size=\"" << h + 2 * t << ' ' << t
    << ' ' << hz << '"' << attrs << '\n';
  x << "<geom name=\"wall_south\" type=\"box\" pos=\"0 " << -(h + t) << ' ' << hz << "\" size=\"" << h + 2 * t << ' '
    << t << ' ' << hz << '"' << attrs << '\n';
  for (size_t i = 0; i < slots.size(); ++i) {
    x << "<body name=\"obstacle_" << i << "\" mocap=\"true\" pos=\"" << 3 * h + 2 + 2.0 * i << ' ' << 3 * h + 2 << ' '
      << hz + kObstacleLift << "\">";
    if (slots[i].box) {
      x << "<geom type=\"box\" size=\"" << slots[i].half_size << ' ' << slots[i].half_size << ' ' << hz << '"';
    } else {
      x << "<geom type=\"cylinder\" size=\"" << slots[i].half_size << ' ' << hz << '"';
    }
    x << R"( contype="1" conaffinity="2" group="1" rgba="0.7 0.3 0.2 1"/></body>)" << '\n';
  }
  return x.str();
}

int joint_id(const mjModel* m, const std::string& name, const std::string& file) {
  const int id = mj_name2id(m, mjOBJ_JOINT, name.c_str());
  if (id < 0) throw std::runtime_error(file + ": expected a joint named '" + name + "'");
  return id;
}

}  // namespace

MobileTask::MobileTask(const MobileRobotSpec& robot) : robot_(robot) {
  const auto& c = robot.scene;
  const std::vector<ObstacleSlot> slots = obstacle_slots(c);
  std::string xml = embedded_text(robot.mjcf);
  const std::string marker = "<!--SCENE-->";
  const size_t at = xml.find(marker);
  if (at == std::string::npos) throw std::runtime_error(robot.mjcf + ": no " + marker + " marker");
  xml.replace(at, marker.size(), scene_xml(c, slots));
  model_ = load_xml_text(robot.mjcf.substr(robot.mjcf.find_last_of('/') + 1), xml);
  mjModel* m = model_;
  m->opt.timestep = c.physics_dt();

  const bool diff = robot.base == BaseKind::kDifferential;
  const std::vector<std::string> wheels = diff ? std::vector<std::string>{"left_wheel", "right_wheel"}
                                               : std::vector<std::string>{"wheel_a", "wheel_b", "wheel_c"};
  for (size_t i = 0; i < wheels.size(); ++i) {
    const int j = joint_id(m, wheels[i], robot.mjcf);
    wheel_joints_.push_back(j);
    wheel_qvel_.push_back(m->jnt_dofadr[j]);
    const int a = mj_name2id(m, mjOBJ_ACTUATOR, wheels[i].c_str());
    if (a != int(i)) {
      throw std::runtime_error(robot.mjcf + ": actuator " + std::to_string(i) + " must be the '" + wheels[i] +
                               "' velocity servo");
    }
    m->actuator_gainprm[a * mjNGAIN + 0] = robot.wheel_kv;
    m->actuator_biasprm[a * mjNBIAS + 2] = -robot.wheel_kv;
    m->actuator_forcelimited[a] = 1;
    m->actuator_forcerange[2 * a] = -robot.wheel_max_torque;
    m->actuator_forcerange[2 * a + 1] = robot.wheel_max_torque;
    if (!diff) roller_qpos_.push_back(m->jnt_qposadr[joint_id(m, "roller_" + wheels[i].substr(6), robot.mjcf)]);
  }
  const int root = joint_id(m, "root", robot.mjcf);
  root_qpos_ = m->jnt_qposadr[root];
  root_qvel_ = m->jnt_dofadr[root];
  const int base_body = m->jnt_bodyid[root];
  const int wheel_geom = mj_name2id(m, mjOBJ_GEOM, wheels[0].c_str());
  if (wheel_geom < 0) throw std::runtime_error(robot.mjcf + ": expected a geom named '" + wheels[0] + "'");
  wheel_radius_ = m->geom_size[3 * wheel_geom];
  // Geometry of the paper's kinematics, read from the MJCF: wheel spacing R (differential) or
  // center-to-wheel distance L (holonomic).
  const int wb0 = m->jnt_bodyid[wheel_joints_[0]];
  if (diff) {
    const int wb1 = m->jnt_bodyid[wheel_joints_[1]];
    wheel_offset_ = std::abs(m->body_pos[3 * wb0 + 1] - m->body_pos[3 * wb1 + 1]);
  } else {
    const int roller_body = m->body_parentid[wb0];
    wheel_offset_ = std::hypot(m->body_pos[3 * roller_body], m->body_pos[3 * roller_body + 1]);
  }

  robot_geom_.assign(m->ngeom, 0);
  world_geom_.assign(m->ngeom, 0);
  for (int g = 0; g < m->ngeom; ++g) {
    robot_geom_[g] = m->body_rootid[m->geom_bodyid[g]] == base_body;
    world_geom_[g] = m->geom_group[g] == kWorldGroup;
  }
  for (size_t i = 0; i < slots.size(); ++i) {
    const int b = mj_name2id(m, mjOBJ_BODY, ("obstacle_" + std::to_string(i)).c_str());
    obstacle_mocap_.push_back(m->body_mocapid[b]);
  }
  // Footprint radius: farthest reach of any robot geom from the base origin, in the plane.
  mjData* d = mj_makeData(m);
  mj_forward(m, d);
  for (int g = 0; g < m->ngeom; ++g) {
    if (!robot_geom_[g]) continue;
    const double r =
        std::hypot(d->geom_xpos[3 * g] - d->xpos[3 * base_body], d->geom_xpos[3 * g + 1] - d->xpos[3 * base_body + 1]);
    robot_radius_ = std::max(robot_radius_, r + m->geom_rbound[g]);
  }
  mj_deleteData(d);

  lidar_ = std::make_unique<Lidar>(m, "lidar", c.lidar_rays(), c.lidar_range(), c.lidar_fov_deg(), kWorldGroup);
  maps_ = std::make_unique<MapGenerator>(c, robot_radius_);

  const double v = robot.max_linear_speed, w = robot.max_angular_speed;
  if (diff) {
    // Straight ahead, gentle arcs (radius 0.6 m at the defaults), tight arcs, and turns in place.
    // With only full-rate turns (0.2 rad and 7.5 cm radius per 0.1 s step) DQN did not learn to
    // line up with a goal 0.1 m wide; SAC with continuous commands did (docs/record/mobile.md).
    commands_ = {{v, 0, 0},          {v, 0, w / 4}, {v, 0, -w / 4}, {v / 2, 0, w / 2},
                 {v / 2, 0, -w / 2}, {0, 0, w / 2}, {0, 0, -w / 2}};
  } else {
    for (int k = 0; k < 8; ++k) commands_.push_back({v * std::cos(k * kPi / 4), v * std::sin(k * kPi / 4), 0});
    commands_.push_back({0, 0, w});
    commands_.push_back({0, 0, -w});
  }
  // Top wheel speed over the corners of the command box: the observation's wheel scale.
  wheel_max_ = 1e-9;
  for (int sx = -1; sx <= 1; sx += 2)
    for (int sy = -1; sy <= 1; sy += 2)
      for (int sw = -1; sw <= 1; sw += 2)
        for (double ws : wheel_speeds({sx * v, diff ? 0.0 : sy * v, sw * w}))
          wheel_max_ = std::max(wheel_max_, std::abs(ws));  // unused third entry is 0

  spec_.name = robot.name;
  const int nw = int(wheels.size());
  spec_.obs_dim = c.lidar_rays() + 3 + nw + 3;
  spec_.num_actions = c.discrete_actions() ? int(commands_.size()) : 0;
  spec_.act_dim = c.discrete_actions() ? 1 : (diff ? 2 : 3);
  spec_.max_episode_steps = c.max_episode_steps();
  spec_.metric_names = {"success", "time_s", "path_m", "collision", "final_distance"};
}

MobileTask::~MobileTask() {
  if (model_) mj_deleteModel(model_);
}

double MobileTask::control_dt() const { return robot_.scene.physics_dt() * robot_.scene.control_substeps(); }

std::unique_ptr<TaskState> MobileTask::make_state() const {
  auto s = std::make_unique<MobileState>();
  s->data = mj_makeData(model_);
  if (!s->data) throw std::runtime_error(spec_.name + ": mj_makeData failed");
  s->scan.resize(lidar_->rays());
  return s;
}

std::array<double, 3> MobileTask::base_command(const float* action) const {
  if (spec_.num_actions > 0) {
    const float a = action[0];
    const long k = std::isfinite(a) ? std::lround(a) : -1;
    if (k < 0 || k >= long(commands_.size()) || std::abs(a - float(k)) > 1e-3f) {
      throw std::invalid_argument(spec_.name + ": discrete action " + std::to_string(a) + " is not an index in [0, " +
                                  std::to_string(commands_.size()) + ")");
    }
    return commands_[k];
  }
  // A NaN action (diverged policy) would poison the simulation; it means stand still.
  auto unit = [](float a) { return std::isnan(a) ? 0.0 : std::clamp(double(a), -1.0, 1.0); };
  const double v = robot_.max_linear_speed, w = robot_.max_angular_speed;
  if (robot_.base == BaseKind::kDifferential) return {unit(action[0]) * v, 0, unit(action[1]) * w};
  return {unit(action[0]) * v, unit(action[1]) * v, unit(action[2]) * w};
}

std::array<double, 3> MobileTask::wheel_speeds(const std::array<double, 3>& cmd) const {
  if (robot_.base == BaseKind::kDifferential) {
    const auto s = differential_wheel_speeds(cmd[0], cmd[2], wheel_radius_, wheel_offset_);
    return {s.left, s.right, 0.0};
  }
  const auto s = holonomic_wheel_speeds(cmd[0], cmd[1], cmd[2], wheel_radius_, wheel_offset_);
  return {s.a, s.b, s.c};
}

void MobileTask::pose(const TaskState& s, double* x, double* y, double* yaw) const {
  const mjtNum* q = s.data->qpos + root_qpos_;
  *x = q[0];
  *y = q[1];
  *yaw = std::atan2(2 * (q[3] * q[6] + q[4] * q[5]), 1 - 2 * (q[5] * q[5] + q[6] * q[6]));
}

void MobileTask::base_velocity(const TaskState& s, double* vx, double* vy, double* w) const {
  double x, y, yaw;
  pose(s, &x, &y, &yaw);
  const mjtNum* v = s.data->qvel + root_qvel_;  // free joint: linear in world, angular in body
  const double c = std::cos(yaw), sn = std::sin(yaw);
  *vx = c * v[0] + sn * v[1];
  *vy = -sn * v[0] + c * v[1];
  *w = v[5];
}

double MobileTask::wheel_speed(const TaskState& s, int i) const { return s.data->qvel[wheel_qvel_[i]]; }

void MobileTask::write_obs(MobileState& s, float* obs) const {
  const auto& c = robot_.scene;
  lidar_->scan(model_, s.data, s.scan.data());
  int k = 0;
  for (double r : s.scan) obs[k++] = float(r / c.lidar_range());
  double vx, vy, w;
  base_velocity(s, &vx, &vy, &w);
  obs[k++] = float(vx / robot_.max_linear_speed);
  obs[k++] = float(vy / robot_.max_linear_speed);
  obs[k++] = float(w / robot_.max_angular_speed);
  for (int i = 0; i < num_wheels(); ++i) obs[k++] = float(wheel_speed(s, i) / wheel_max_);
  double x, y, yaw;
  pose(s, &x, &y, &yaw);
  const double dx = s.map.goal_x - x, dy = s.map.goal_y - y;
  const double err = wrap_angle(std::atan2(dy, dx) - yaw);
  obs[k++] = float(std::hypot(dx, dy) / c.arena_half_size());
  obs[k++] = float(std::cos(err));
  obs[k++] = float(std::sin(err));
}

bool MobileTask::touches_obstacle(const mjData* d) const {
  for (int i = 0; i < d->ncon; ++i) {
    const int g1 = d->contact[i].geom1, g2 = d->contact[i].geom2;
    if ((robot_geom_[g1] && world_geom_[g2]) || (robot_geom_[g2] && world_geom_[g1])) return true;
  }
  return false;
}

void MobileTask::reset(TaskState& s, uint64_t seed, float* obs) const {
  s.rng.seed(seed);
  reset_to(s, maps_->draw(s.rng), obs);
}

void MobileTask::reset_to(TaskState& ts, const MobileMap& map, float* obs) const {
  MobileState& s = static_cast<MobileState&>(ts);
  mjData* d = s.data;
  mj_resetData(model_, d);
  s.map = map;
  // mj_resetData parked every obstacle slot outside the walls (its body_pos); place the map's.
  for (const auto& o : map.obstacles) {
    if (o.slot < 0 || o.slot >= int(obstacle_mocap_.size())) {
      throw std::invalid_argument(spec_.name + ": obstacle slot " + std::to_string(o.slot) + " out of range");
    }
    mjtNum* p = d->mocap_pos + 3 * obstacle_mocap_[o.slot];
    mjtNum* q = d->mocap_quat + 4 * obstacle_mocap_[o.slot];
    p[0] = o.x;
    p[1] = o.y;
    q[0] = std::cos(o.yaw / 2);
    q[1] = 0;
    q[2] = 0;
    q[3] = std::sin(o.yaw / 2);
  }
  mjtNum* q = d->qpos + root_qpos_;
  q[0] = map.start_x;
  q[1] = map.start_y;
  q[3] = std::cos(map.start_yaw / 2);
  q[6] = std::sin(map.start_yaw / 2);
  mj_forward(model_, d);
  s.step = 0;
  s.episode_return = 0;
  s.path_length = 0;
  s.collided = false;
  s.reached = false;
  s.last_distance = std::hypot(map.goal_x - map.start_x, map.goal_y - map.start_y);
  s.trajectory.clear();
  if (s.record_trajectory) {
    s.trajectory.push_back(float(map.start_x));
    s.trajectory.push_back(float(map.start_y));
  }
  write_obs(s, obs);
}

StepResult MobileTask::step(TaskState& ts, const float* action, float* obs) const {
  MobileState& s = static_cast<MobileState&>(ts);
  const auto& c = robot_.scene;
  mjData* d = s.data;
  const std::array<double, 3> wheels = wheel_speeds(base_command(action));
  for (int i = 0; i < num_wheels(); ++i) d->ctrl[i] = wheels[i];
  double x0, y0, yaw;
  pose(s, &x0, &y0, &yaw);
  for (int k = 0; k < c.control_substeps(); ++k) {
    mj_step(model_, d);
    // Omni wheels: return the free roller to zero (see kaya.xml); the sphere is symmetric.
    for (int r : roller_qpos_) d->qpos[r] = 0;
    if (touches_obstacle(d)) s.collided = true;
    if (s.after_physics_step) s.after_physics_step();
  }
  double x, y;
  pose(s, &x, &y, &yaw);
  s.path_length += std::hypot(x - x0, y - y0);
  if (s.record_trajectory) {
    s.trajectory.push_back(float(x));
    s.trajectory.push_back(float(y));
  }
  write_obs(s, obs);

  s.step += 1;
  const double dist = std::hypot(s.map.goal_x - x, s.map.goal_y - y);
  s.last_distance = dist;
  // The mobile-robots paper eq. 9; the step weight 1 - i / N shrinks both the distance cost and the landing
  // reward as the episode goes on.
  const double weight = 1.0 - double(s.step) / double(c.max_episode_steps());
  StepResult r;
  if (s.collided) {
    r.reward = float(-c.collision_penalty());
    r.terminated = true;
  } else if (dist < c.goal_radius()) {
    s.reached = true;
    r.reward = float(c.landing_reward() * weight);
    r.terminated = true;
  } else {
    r.reward = float(-c.distance_weight() * dist * weight);
  }
  r.truncated = !r.terminated && s.step >= c.max_episode_steps();
  s.episode_return += r.reward;
  return r;
}

void MobileTask::episode_metrics(const TaskState& ts, float* out) const {
  const MobileState& s = static_cast<const MobileState&>(ts);
  out[0] = s.reached ? 1.f : 0.f;
  out[1] = float(s.step * control_dt());
  out[2] = float(s.path_length);
  out[3] = s.collided ? 1.f : 0.f;
  out[4] = float(s.last_distance);
}

std::unique_ptr<Task> make_jetbot_task(const config::TaskConfig& cfg) {
  const auto& j = cfg.jetbot();
  // The loader has checked a config read from a file; this one may have been built in code.
  check_config(j);
  MobileRobotSpec r;
  r.name = "jetbot";
  r.mjcf = "mobile/jetbot.xml";
  r.base = BaseKind::kDifferential;
  r.max_linear_speed = j.max_linear_speed();
  r.max_angular_speed = j.max_angular_speed();
  r.wheel_kv = j.wheel_kv();
  r.wheel_max_torque = j.wheel_max_torque();
  r.scene = j.scene();
  return std::make_unique<MobileTask>(r);
}

std::unique_ptr<Task> make_kaya_task(const config::TaskConfig& cfg) {
  const auto& k = cfg.kaya();
  check_config(k);
  MobileRobotSpec r;
  r.name = "kaya";
  r.mjcf = "mobile/kaya.xml";
  r.base = BaseKind::kHolonomic;
  r.max_linear_speed = k.max_linear_speed();
  r.max_angular_speed = k.max_angular_speed();
  r.wheel_kv = k.wheel_kv();
  r.wheel_max_torque = k.wheel_max_torque();
  r.scene = k.scene();
  return std::make_unique<MobileTask>(r);
}

void MobileTask::view(const TaskState& base, const mjData* pose, int root, TaskView& out) const {
  const auto& s = static_cast<const MobileState&>(base);
  out.elevation = -60;
  out.frame_point[0] = s.map.goal_x;
  out.frame_point[1] = s.map.goal_y;
  out.frame_point[2] = pose->xpos[3 * root + 2];
  out.frame_extent = scene().arena_half_size();
  ViewMarker goal;
  goal.pos[0] = s.map.goal_x;
  goal.pos[1] = s.map.goal_y;
  goal.pos[2] = 0.002;
  goal.radius = scene().goal_radius();
  goal.half_height = 0.002;
  out.markers.push_back(goal);
}

}  // namespace farm::robots::mobile
