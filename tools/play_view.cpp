#include "play_view.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

namespace farm::tools {

namespace {

// The camera's look-at point follows the root body through first-order lags of these time
// constants (s): closely across the ground, slowly up and down, so a trunk's bobbing does not
// shake the picture.
constexpr double kFollowSecondsXY = 0.1, kFollowSecondsZ = 0.5;
// Default distances: this many robot radii, or arena half sizes for the mobile robots (the goal and
// the obstacles around the robot stay in the picture).
constexpr double kRobotRadii = 2.5;
// Mobile robots: this many start-to-goal distances, at least the first and at most the second
// number of arena half sizes.
constexpr double kGoalDistances = 1.8, kMinArenaHalfSizes = 0.6, kMaxArenaHalfSizes = 2.2;
// A backdrop stands this many robot radii behind the look-at point of a model without a floor.
constexpr double kBackdropRadii = 1.5;
// The floor grid: lines about a robot radius apart (rounded to 1, 2 or 5 times a power of 10 m),
// at least a camera distance over kGridLinesPerDistance, drawn kGridReach camera distances around
// the look-at point, kGridLineWidth of the spacing wide.
constexpr double kGridReach = 2.5, kGridLineWidth = 0.02, kGridLinesPerDistance = 8;
constexpr float kGridRgba[4] = {0.25f, 0.27f, 0.30f, 1};

double round_spacing(double x) {
  const double p = std::pow(10.0, std::floor(std::log10(x)));
  for (double k : {1.0, 2.0, 5.0})
    if (x <= k * p * 1.5) return k * p;
  return 10 * p;
}

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
  grid_spacing_ = 0;
  for (int g = 0; g < m->ngeom; ++g) {
    if (m->geom_bodyid[g] != 0) continue;
    has_floor_ = has_floor_ || m->geom_type[g] == mjGEOM_PLANE || m->geom_type[g] == mjGEOM_HFIELD;
    // A level plane under the robot: the grid lies on it.
    if (m->geom_type[g] == mjGEOM_PLANE && pose->geom_xmat[9 * g + 8] > 0.999 && pose->geom_xpos[3 * g + 2] <= r[2]) {
      floor_z_ = pose->geom_xpos[3 * g + 2];
      grid_spacing_ = 1;  // sized below, once the camera's distance is known
    }
  }

  robots::TaskView view;
  task_.view(s, pose, root_, view);
  if (choice_.distance > 0) {
    distance_ = choice_.distance;
  } else if (view.frame_extent > 0) {
    const double half = view.frame_extent;
    const double to_goal = std::hypot(view.frame_point[0] - r[0], view.frame_point[1] - r[1]);
    distance_ = std::clamp(kGoalDistances * to_goal, kMinArenaHalfSizes * half, kMaxArenaHalfSizes * half);
  } else {
    distance_ = kRobotRadii * radius;
  }
  elevation_ = choice_.elevation != 0 ? choice_.elevation : view.elevation;
  // About a robot radius apart, but no denser than an eighth of the camera's distance: an arena
  // seen whole keeps a few lines across it.
  if (grid_spacing_ > 0) grid_spacing_ = round_spacing(std::max(radius, distance_ / kGridLinesPerDistance));
  target(s, pose, lookat_);
  last_time_ = pose->time;
}

void PlayView::target(const robots::TaskState& s, const mjData* pose, double out[3]) const {
  const mjtNum* r = pose->xpos + 3 * root_;
  for (int k = 0; k < 3; ++k) out[k] = r[k];
  robots::TaskView view;
  task_.view(s, pose, root_, view);
  if (view.frame_extent > 0) {
    out[0] = 0.5 * (r[0] + view.frame_point[0]);
    out[1] = 0.5 * (r[1] + view.frame_point[1]);
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
  if (grid_spacing_ > 0) {
    // Lines along x and along y at multiples of the spacing, just above the floor.
    const double d = grid_spacing_, reach = kGridReach * distance_, w = kGridLineWidth * d, h = 0.002;
    const double x0 = std::floor((lookat_[0] - reach) / d) * d, y0 = std::floor((lookat_[1] - reach) / d) * d;
    const int n = int(std::ceil(2 * reach / d)) + 1;
    for (int i = 0; i <= n; ++i) {
      const mjtNum along_x[3] = {reach, w, h}, at_y[3] = {lookat_[0], y0 + i * d, floor_z_ + h};
      add_geom(scn, mjGEOM_BOX, along_x, at_y, kGridRgba);
      const mjtNum along_y[3] = {w, reach, h}, at_x[3] = {x0 + i * d, lookat_[1], floor_z_ + h};
      add_geom(scn, mjGEOM_BOX, along_y, at_x, kGridRgba);
    }
  }
  robots::TaskView view;
  task_.view(s, pose, root_, view);
  for (const auto& mk : view.markers) {
    if (mk.kind == robots::ViewMarker::kArrow) {
      add_arrow(scn, mk.pos, mk.to, mk.radius, mk.rgba);
    } else {
      // mjv_initGeom takes a cylinder's size as a model does: radius, half height.
      const mjtNum size[3] = {mk.radius, mk.half_height, 0};
      add_geom(scn, mjGEOM_CYLINDER, size, mk.pos, mk.rgba);
    }
  }
}

std::vector<std::pair<std::string, std::string>> PlayView::rows(const robots::TaskState& s, const mjData* pose) const {
  robots::TaskView view;
  task_.view(s, pose, root_, view);
  return view.rows;
}

}  // namespace farm::tools
