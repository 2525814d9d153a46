#include "mobile/obstacle_map.h"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <stdexcept>
#include <string>

#include "check.h"

namespace farm::robots::mobile {

namespace {
constexpr double kPi = 3.14159265358979323846;
}  // namespace

double ObstacleSlot::bound() const { return box ? half_size * std::sqrt(2.0) : half_size; }

std::vector<ObstacleSlot> obstacle_slots(const config::MobileSceneConfig& cfg) {
  const int k = cfg.max_obstacles();
  std::vector<ObstacleSlot> slots(k);
  for (int i = 0; i < k; ++i) {
    const double f = k > 1 ? double(i) / (k - 1) : 0.0;
    slots[i].box = i % 2 == 0;
    slots[i].half_size =
        cfg.obstacle_min_half_size() + f * (cfg.obstacle_max_half_size() - cfg.obstacle_min_half_size());
  }
  return slots;
}

double distance_to_obstacle(const ObstacleSlot& slot, const PlacedObstacle& o, double x, double y) {
  const double dx = x - o.x, dy = y - o.y;
  if (!slot.box) return std::max(0.0, std::hypot(dx, dy) - slot.half_size);
  // Into the box's frame, then the distance to an axis-aligned square.
  const double c = std::cos(o.yaw), s = std::sin(o.yaw);
  const double lx = std::abs(c * dx + s * dy) - slot.half_size;
  const double ly = std::abs(-s * dx + c * dy) - slot.half_size;
  return std::hypot(std::max(lx, 0.0), std::max(ly, 0.0));
}

MapGenerator::MapGenerator(const config::MobileSceneConfig& cfg, double robot_radius)
    : cfg_(cfg), robot_radius_(robot_radius), slots_(obstacle_slots(cfg)) {
  if (cfg.static_map()) {
    std::mt19937_64 rng(cfg.static_map_seed());
    draw_obstacles(rng, static_map_);
  }
  // The config's ranges are the loader's (common/config.cpp); this one needs the robot's model too.
  farm::require(robot_radius + cfg.clearance() < cfg.arena_half_size(),
                "mobile scene: the robot (radius " + std::to_string(robot_radius) +
                    " m) plus clearance does not fit in the arena");
}

void MapGenerator::draw_obstacles(std::mt19937_64& rng, MobileMap& map) const {
  std::uniform_int_distribution<int> count(cfg_.min_obstacles(), cfg_.max_obstacles());
  const int n = count(rng);
  std::vector<int> order(slots_.size());
  std::iota(order.begin(), order.end(), 0);
  std::shuffle(order.begin(), order.end(), rng);
  std::uniform_real_distribution<double> yaw(-kPi, kPi);
  map.obstacles.clear();
  const double h = cfg_.arena_half_size();
  for (int i = 0; i < n; ++i) {
    PlacedObstacle o;
    o.slot = order[i];
    const double b = slots_[o.slot].bound();
    std::uniform_real_distribution<double> pos(-h + b, h - b);
    o.x = pos(rng);
    o.y = pos(rng);
    o.yaw = slots_[o.slot].box ? yaw(rng) : 0.0;
    map.obstacles.push_back(o);
  }
}

bool MapGenerator::is_free(const MobileMap& map, double x, double y) const {
  const double keep = robot_radius_ + cfg_.clearance();
  const double h = cfg_.arena_half_size();
  if (std::abs(x) > h - keep || std::abs(y) > h - keep) return false;
  for (const auto& o : map.obstacles) {
    if (distance_to_obstacle(slots_[o.slot], o, x, y) < keep) return false;
  }
  return true;
}

MobileMap MapGenerator::draw(std::mt19937_64& rng) const {
  const double h = cfg_.arena_half_size();
  std::uniform_real_distribution<double> pos(-h, h), yaw(-kPi, kPi);
  MobileMap map;
  for (int attempt = 0; attempt < cfg_.max_reset_tries(); ++attempt) {
    if (cfg_.static_map()) {
      map = static_map_;
    } else {
      draw_obstacles(rng, map);
    }
    // A few tries for start and goal on each obstacle map before drawing a new map.
    for (int k = 0; k < 20; ++k) {
      map.start_x = pos(rng);
      map.start_y = pos(rng);
      if (!is_free(map, map.start_x, map.start_y)) continue;
      map.goal_x = pos(rng);
      map.goal_y = pos(rng);
      if (!is_free(map, map.goal_x, map.goal_y)) continue;
      if (std::hypot(map.goal_x - map.start_x, map.goal_y - map.start_y) < cfg_.min_start_goal_distance()) {
        continue;
      }
      map.start_yaw = yaw(rng);
      return map;
    }
  }
  throw std::runtime_error("mobile scene: no free start and goal found in " + std::to_string(cfg_.max_reset_tries()) +
                           " obstacle maps; lower max_obstacles, obstacle sizes, clearance or "
                           "min_start_goal_distance, or enlarge arena_half_size");
}

}  // namespace farm::robots::mobile
