// A planar lidar: rays cast with mj_ray from a site, in the site's horizontal plane, against the
// geoms of one group (walls and obstacles), so the robot never sees itself.
#pragma once

#include <mujoco/mujoco.h>

#include <vector>

namespace farm::robots::mobile {

class Lidar {
 public:
  // rays spread over fov_deg: a full circle as rays i * 360 / n, a partial one from -fov/2 to
  // +fov/2; ray 0 points along the site's x axis (ahead) for a full circle. Throws
  // std::invalid_argument if the site does not exist.
  Lidar(const mjModel* m, const char* site, int rays, double range, double fov_deg, int geom_group);
  int rays() const { return int(angles_.size()); }
  double range() const { return range_; }
  double angle(int i) const { return angles_[i]; }  // rad, in the site frame
  // Distances (m) along each ray to the nearest geom of the group, `range` where none is closer.
  // Reads the geom and site poses of the last mj_forward / mj_step.
  void scan(const mjModel* m, const mjData* d, double* out) const;

 private:
  int site_ = -1;
  double range_ = 1.0;
  std::vector<double> angles_, cos_, sin_;
  mjtByte group_[mjNGROUP] = {0};
};

}  // namespace farm::robots::mobile
