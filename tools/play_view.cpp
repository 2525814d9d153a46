#include "play_view.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "mclari/mclari_task.h"
#include "mclari/phase_groups.h"
#include "mclari/terrain.h"
#include "mobile/mobile_task.h"
#include "quadruped/quadruped_task.h"

namespace farm::tools {

namespace {

// The camera's look-at point follows the root body through first-order lags of these time
// constants (s): closely across the ground, slowly up and down, so a trunk's bobbing does not
// shake the picture.
constexpr double kFollowSecondsXY = 0.1, kFollowSecondsZ = 0.5;
// Default distances: this many robot radii, or arena half sizes for the mobile robots (the goal and
// the obstacles around the robot stay in the picture).
constexpr double kRobotRadii = 3.5;
// Mobile robots: this many start-to-goal distances, at least the first and at most the second
// number of arena half sizes.
constexpr double kGoalDistances = 1.8, kMinArenaHalfSizes = 0.6, kMaxArenaHalfSizes = 2.2;
// A backdrop stands this many robot radii behind the look-at point of a model without a floor.
constexpr double kBackdropRadii = 1.5;

void add_geom(mjvScene& scn, int type, const mjtNum size[3], const mjtNum pos[3], const float rgba[4]) {
  if (scn.ngeom >= scn.maxgeom) return;
  mjvGeom* g = scn.geoms + scn.ngeom++;
  const mjtNum eye[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  mjv_initGeom(g, type, size, pos, eye, rgba);
  g->category = mjCAT_DECOR;
}

void add_arrow(mjvScene& scn, const mjtNum from[3], const mjtNum to[3], double width, const float rgba[4]) {
  if (scn.ngeom >= scn.maxgeom) return;
  mjvGeom* g = scn.geoms + scn.ngeom++;
  mjv_initGeom(g, mjGEOM_ARROW, nullptr, nullptr, nullptr, rgba);
  mjv_makeConnector(g, mjGEOM_ARROW, width, from[0], from[1], from[2], to[0], to[1], to[2]);
  g->category = mjCAT_DECOR;
}

std::string format(const char* f, double a, double b = 0, double c = 0) {
  char text[128];
  std::snprintf(text, sizeof text, f, a, b, c);
  return text;
}

}  // namespace

PlayView::PlayView(const robots::Task& task, const CameraChoice& choice) : task_(task), choice_(choice) {}

bool PlayView::is_robot_body(int body) const {
  return m_ && body > 0 && body < m_->nbody && m_->body_rootid[body] == m_->body_rootid[root_];
}

void PlayView::start_episode(const robots::TaskState& s, const mjModel* m, const mjData* pose) {
  m_ = m;
  // The root: the body with a free joint (the mobile robots, the legged ones), else the first body
  // under the world (a pendulum's rod, the cart of the cart-pole).
  root_ = m->nbody > 1 ? 1 : 0;
  for (int j = 0; j < m->njnt; ++j) {
    if (m->jnt_type[j] == mjJNT_FREE) {
      root_ = m->jnt_bodyid[j];
      break;
    }
  }
  const char* name = mj_id2name(m, mjOBJ_BODY, root_);
  root_name_ = name ? name : "body " + std::to_string(root_);
  double radius = 0;
  const mjtNum* r = pose->xpos + 3 * root_;
  for (int g = 0; g < m->ngeom; ++g) {
    if (!is_robot_body(m->geom_bodyid[g])) continue;
    const mjtNum* p = pose->geom_xpos + 3 * g;
    radius = std::max(radius, std::hypot(p[0] - r[0], p[1] - r[1], p[2] - r[2]) + m->geom_rbound[g]);
  }
  if (radius <= 0) radius = m->stat.extent > 0 ? m->stat.extent : 1.0;
  radius_ = radius;
  has_floor_ = false;
  for (int g = 0; g < m->ngeom; ++g)
    has_floor_ =
        has_floor_ || (m->geom_bodyid[g] == 0 && (m->geom_type[g] == mjGEOM_PLANE || m->geom_type[g] == mjGEOM_HFIELD));

  const auto* mobile = dynamic_cast<const robots::mobile::MobileTask*>(&task_);
  const auto* legged = dynamic_cast<const robots::quadruped::QuadrupedTask*>(&task_);
  const auto* mclari = dynamic_cast<const robots::McLariTask*>(&task_);
  if (choice_.distance > 0) {
    distance_ = choice_.distance;
  } else if (mobile) {
    const auto& ms = static_cast<const robots::mobile::MobileState&>(s);
    const double half = mobile->scene().arena_half_size();
    const double to_goal = std::hypot(ms.map.goal_x - r[0], ms.map.goal_y - r[1]);
    distance_ = std::clamp(kGoalDistances * to_goal, kMinArenaHalfSizes * half, kMaxArenaHalfSizes * half);
  } else {
    distance_ = kRobotRadii * radius;
  }
  elevation_ = choice_.elevation != 0 ? choice_.elevation : mobile ? -60 : mclari ? -35 : legged ? -20 : -10;
  target(s, pose, lookat_);
  last_time_ = pose->time;
}

void PlayView::target(const robots::TaskState& s, const mjData* pose, double out[3]) const {
  const mjtNum* r = pose->xpos + 3 * root_;
  for (int k = 0; k < 3; ++k) out[k] = r[k];
  if (dynamic_cast<const robots::mobile::MobileTask*>(&task_)) {
    const auto& ms = static_cast<const robots::mobile::MobileState&>(s);
    out[0] = 0.5 * (r[0] + ms.map.goal_x);
    out[1] = 0.5 * (r[1] + ms.map.goal_y);
  }
}

void PlayView::aim(const robots::TaskState& s, const mjData* pose, mjvCamera& cam) {
  const double dt = std::max(0.0, pose->time - last_time_);
  last_time_ = pose->time;
  const double a[3] = {1 - std::exp(-dt / kFollowSecondsXY), 1 - std::exp(-dt / kFollowSecondsXY),
                       1 - std::exp(-dt / kFollowSecondsZ)};
  double want[3];
  target(s, pose, want);
  for (int k = 0; k < 3; ++k) lookat_[k] += a[k] * (want[k] - lookat_[k]);
  mjv_defaultCamera(&cam);
  cam.type = mjCAMERA_FREE;
  for (int k = 0; k < 3; ++k) cam.lookat[k] = lookat_[k];
  cam.distance = distance_;
  cam.azimuth = choice_.azimuth;
  cam.elevation = elevation_;
}

void PlayView::decorate(const robots::TaskState& s, const mjData* pose, mjvScene& scn) const {
  if (!has_floor_) {
    // A light wall behind the robot, facing the camera (upright, across its azimuth).
    const double az = choice_.azimuth * M_PI / 180, ca = std::cos(az), sa = std::sin(az);
    const double back = kBackdropRadii * radius_, half = 4 * distance_;
    const mjtNum pos[3] = {lookat_[0] + back * ca, lookat_[1] + back * sa, lookat_[2]};
    // Columns: the plane's x (across the view), y (up) and normal (towards the camera).
    const mjtNum mat[9] = {sa, 0, -ca, -ca, 0, -sa, 0, 1, 0};
    const mjtNum size[3] = {half, half, half / 10};
    const float grey[4] = {0.82f, 0.84f, 0.88f, 1};
    if (scn.ngeom < scn.maxgeom) {
      mjvGeom* g = scn.geoms + scn.ngeom++;
      mjv_initGeom(g, mjGEOM_PLANE, size, pos, mat, grey);
      g->category = mjCAT_DECOR;
    }
  }
  if (const auto* mobile = dynamic_cast<const robots::mobile::MobileTask*>(&task_)) {
    // The goal region, a flat red disc on the floor.
    const auto& ms = static_cast<const robots::mobile::MobileState&>(s);
    const double radius = mobile->scene().goal_radius();
    // mjv_initGeom takes a cylinder's size as a model does: radius, half height.
    const mjtNum size[3] = {radius, 0.002, 0}, pos[3] = {ms.map.goal_x, ms.map.goal_y, 0.002};
    const float red[4] = {0.9f, 0.1f, 0.1f, 0.7f};
    add_geom(scn, mjGEOM_CYLINDER, size, pos, red);
  } else if (dynamic_cast<const robots::quadruped::QuadrupedTask*>(&task_)) {
    // The velocity command, turned from the base frame to the world by the trunk's yaw, as an
    // arrow above the trunk one second long.
    const auto& qs = static_cast<const robots::quadruped::QuadrupedState&>(s);
    const mjtNum* x = pose->xmat + 9 * root_;
    const double yaw = std::atan2(x[3], x[0]);
    const double vx = qs.command[0] * std::cos(yaw) - qs.command[1] * std::sin(yaw);
    const double vy = qs.command[0] * std::sin(yaw) + qs.command[1] * std::cos(yaw);
    if (std::hypot(vx, vy) > 1e-3) {
      const mjtNum* p = pose->xpos + 3 * root_;
      const mjtNum from[3] = {p[0], p[1], p[2] + 0.15}, to[3] = {p[0] + vx, p[1] + vy, p[2] + 0.15};
      const float green[4] = {0.1f, 0.8f, 0.2f, 0.9f};
      add_arrow(scn, from, to, 0.02, green);
    }
  } else if (const auto* mclari = dynamic_cast<const robots::McLariTask*>(&task_)) {
    // The target the microbot walks to: a disc of the radius that counts as reached.
    const auto& cs = static_cast<const robots::McLariState&>(s);
    const double radius = mclari->config().target_radius();
    const double z = mclari->ground_height(cs.target[0], cs.target[1], cs.terrain);
    const mjtNum size[3] = {radius, 0.1, 0}, pos[3] = {cs.target[0], cs.target[1], z + 0.1};
    const float red[4] = {0.9f, 0.1f, 0.1f, 0.7f};
    add_geom(scn, mjGEOM_CYLINDER, size, pos, red);
  }
}

std::vector<std::pair<std::string, std::string>> PlayView::rows(const robots::TaskState& s) const {
  if (dynamic_cast<const robots::quadruped::QuadrupedTask*>(&task_)) {
    const auto& qs = static_cast<const robots::quadruped::QuadrupedState&>(s);
    return {{"command", format("vx %+.2f vy %+.2f yaw %+.2f", qs.command[0], qs.command[1], qs.command[2])}};
  }
  if (dynamic_cast<const robots::McLariTask*>(&task_)) {
    const auto& cs = static_cast<const robots::McLariState&>(s);
    return {{"terrain", robots::mclari::terrain_name(cs.terrain)},
            {"gait", cs.last.frequency == 0
                         ? std::string("-")  // before the first step
                         : std::to_string(cs.last.frequency) + " Hz, " + robots::mclari::group_name(cs.last.group)}};
  }
  return {};
}

}  // namespace farm::tools
