#include "mobile/lidar.h"

#include <cmath>
#include <stdexcept>
#include <string>

namespace farm::robots::mobile {

Lidar::Lidar(const mjModel* m, const char* site, int rays, double range, double fov_deg, int geom_group)
    : range_(range) {
  site_ = mj_name2id(m, mjOBJ_SITE, site);
  if (site_ < 0) throw std::invalid_argument(std::string("lidar: the model has no site '") + site + "'");
  if (geom_group < 0 || geom_group >= mjNGROUP) {
    throw std::invalid_argument("lidar: geom group " + std::to_string(geom_group) + " out of range");
  }
  group_[geom_group] = 1;
  const double fov = fov_deg * M_PI / 180.0;
  for (int i = 0; i < rays; ++i) {
    double a;
    if (fov_deg >= 360.0) {
      a = fov * i / rays;
    } else {
      a = rays > 1 ? -fov / 2 + fov * i / (rays - 1) : 0.0;
    }
    angles_.push_back(a);
    cos_.push_back(std::cos(a));
    sin_.push_back(std::sin(a));
  }
}

void Lidar::scan(const mjModel* m, const mjData* d, double* out) const {
  const mjtNum* p = d->site_xpos + 3 * site_;
  const mjtNum* r = d->site_xmat + 9 * site_;  // row-major: world = R * local
  for (size_t i = 0; i < angles_.size(); ++i) {
    // The site's local direction (cos a, sin a, 0) in world coordinates, flattened onto the
    // horizontal plane so that a tilting body still scans level.
    mjtNum v[3] = {r[0] * cos_[i] + r[1] * sin_[i], r[3] * cos_[i] + r[4] * sin_[i], 0};
    const mjtNum n = std::sqrt(v[0] * v[0] + v[1] * v[1]);
    if (n < 1e-9) {
      out[i] = range_;
      continue;
    }
    v[0] /= n;
    v[1] /= n;
    int geom = -1;
    const mjtNum dist = mj_ray(m, d, p, v, group_, 1, -1, &geom);
    out[i] = (dist < 0 || dist > range_) ? range_ : dist;
  }
}

}  // namespace farm::robots::mobile
