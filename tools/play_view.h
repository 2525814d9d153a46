// What farm-play shows of a task besides the model: a camera that follows the robot's root body
// (its distance from the robot's size; where the task frames a point with the robot, a goal, the
// point between the two, far enough for both), the markers and overlay rows the task declares
// (Task::view: the Jetbot's and Kaya's goal, a legged robot's velocity command, the microbot's
// target and gait), a grid on a flat floor (fixed to the world, so that motion shows against it),
// and a backdrop behind a robot that has no floor (the pendulums).
#pragma once

#include <mujoco/mujoco.h>

#include <string>
#include <utility>
#include <vector>

#include "task.h"

namespace farm::tools {

struct CameraChoice {
  double distance = 0;   // 0: from the robot's size (or the arena)
  double azimuth = 90;   // degrees; 90 looks along +y, at the x-z plane the pendulums swing in
  double elevation = 0;  // degrees below the horizon when negative; 0: the task's default
};

class PlayView {
 public:
  PlayView(const robots::Task& task, const CameraChoice& choice);

  // After a reset, with the model the episode runs on and its first pose (kinematics done).
  void start_episode(const robots::TaskState& s, const mjModel* m, const mjData* pose);
  // The camera for the pose at time t: the look-at point follows the root body (the mobile
  // robots: the point halfway to the goal), smoothed.
  void aim(const robots::TaskState& s, const mjData* pose, mjvCamera& cam);
  double distance() const { return distance_; }
  // Markers for the state's task (goal, command, target) added to the scene.
  void decorate(const robots::TaskState& s, const mjData* pose, mjvScene& scn) const;
  // Rows for the overlay (name, value) that only this task has (terrain, command, ...).
  std::vector<std::pair<std::string, std::string>> rows(const robots::TaskState& s, const mjData* pose) const;
  // Bodies of the robot (the root body's tree): what the camera must keep in view.
  bool is_robot_body(int body) const;
  int root_body() const { return root_; }
  std::string root_name() const { return root_name_; }

 private:
  // Where the camera looks for this pose, before smoothing.
  void target(const robots::TaskState& s, const mjData* pose, double out[3]) const;

  const robots::Task& task_;
  CameraChoice choice_;
  const mjModel* m_ = nullptr;
  int root_ = 0;
  std::string root_name_;
  double distance_ = 1, elevation_ = -15, radius_ = 1;
  bool has_floor_ = false;
  // A flat floor's height and the spacing of the grid drawn on it (0: no flat floor, no grid).
  double floor_z_ = 0, grid_spacing_ = 0;
  double lookat_[3] = {0, 0, 0};
  double last_time_ = 0;
};

}  // namespace farm::tools
