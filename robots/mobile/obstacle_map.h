// Random obstacle maps for the mobile-robot arena (mobile-robots paper §3.1-3.2): a square arena with walls,
// a random number of obstacles of several sizes and shapes, and a start pose and goal drawn in
// free space. The MuJoCo model holds a fixed set of obstacle slots (shape and size per slot, see
// obstacle_slots()); a map says which slots are in use and where they stand.
#pragma once

#include <random>
#include <vector>

#include "farm_config.pb.h"

namespace farm::robots::mobile {

struct ObstacleSlot {
  bool box = true;         // box with half extents (half_size, half_size), else a cylinder
  double half_size = 0.1;  // box half extent or cylinder radius (m)
  double bound() const;    // radius of the circle that holds the footprint
};

struct PlacedObstacle {
  int slot = 0;
  double x = 0, y = 0, yaw = 0;
};

struct MobileMap {
  std::vector<PlacedObstacle> obstacles;
  double start_x = 0, start_y = 0, start_yaw = 0;
  double goal_x = 0, goal_y = 0;
};

// max_obstacles slots, sizes spread evenly over [obstacle_min_half_size, obstacle_max_half_size],
// boxes and cylinders alternating.
std::vector<ObstacleSlot> obstacle_slots(const config::MobileSceneConfig& cfg);

// Distance from (x, y) to the footprint of obstacle o (0 inside).
double distance_to_obstacle(const ObstacleSlot& slot, const PlacedObstacle& o, double x, double y);

class MapGenerator {
 public:
  // robot_radius: the robot's footprint radius; start and goal keep robot_radius + clearance
  // from every obstacle and wall.
  MapGenerator(const config::MobileSceneConfig& cfg, double robot_radius);
  const std::vector<ObstacleSlot>& slots() const { return slots_; }
  // A fresh map from rng; with static_map the obstacles are always those drawn from
  // static_map_seed and only start and goal come from rng. Throws std::runtime_error when no
  // free start and goal are found in max_reset_tries draws.
  MobileMap draw(std::mt19937_64& rng) const;
  // Whether (x, y) keeps robot_radius + clearance from the walls and every obstacle of `map`.
  bool is_free(const MobileMap& map, double x, double y) const;

 private:
  void draw_obstacles(std::mt19937_64& rng, MobileMap& map) const;
  config::MobileSceneConfig cfg_;
  double robot_radius_;
  std::vector<ObstacleSlot> slots_;
  MobileMap static_map_;
};

}  // namespace farm::robots::mobile
