// Goal reaching among random obstacles for the wheeled robots of the mobile-robots paper: Jetbot (differential)
// and Kaya (three omni wheels). The agent commands the base, (V, W) or (Vx, Vy, W), either as
// the index of a discrete command (DQN) or as a box in [-1, 1] scaled to the top speeds; the
// seed's kinematics (kinematics.h) turn it into wheel speeds that velocity servos track.
// Observation: lidar distances / range (rays), base velocity in the base frame (Vx, Vy, W) over
// the top speeds, wheel speeds over the top wheel speed, distance to the goal / arena_half_size,
// cos and sin of the heading error to the goal. Reward: mobile-robots paper eq. 9.
#pragma once

#include <array>
#include <memory>
#include <string>
#include <vector>

#include "mobile/lidar.h"
#include "mobile/obstacle_map.h"
#include "task.h"

namespace farm::robots::mobile {

enum class BaseKind { kDifferential, kHolonomic };

struct MobileState : TaskState {
  MobileMap map;
  double path_length = 0;    // m driven this episode
  double last_distance = 0;  // to the goal, after the last step
  bool collided = false, reached = false;
  bool record_trajectory = false;  // tools: keep (x, y) after reset and every step
  std::vector<float> trajectory;   // x0, y0, x1, y1, ...
  std::vector<double> scan;        // lidar scratch
};

struct MobileRobotSpec {
  std::string name;  // task name
  std::string mjcf;  // embedded file, e.g. "mobile/jetbot.xml"
  BaseKind base = BaseKind::kDifferential;
  double max_linear_speed = 0.3, max_angular_speed = 2.0, wheel_kv = 0.05;
  double wheel_max_torque = 0.1;  // N m, the wheel motors' torque limit
  config::MobileSceneConfig scene;
};

class MobileTask final : public Task {
 public:
  // `robot` comes from a checked section (make_jetbot_task and make_kaya_task check it); throws
  // std::invalid_argument when the robot does not fit the arena.
  explicit MobileTask(const MobileRobotSpec& robot);
  ~MobileTask() override;
  MobileTask(const MobileTask&) = delete;
  MobileTask& operator=(const MobileTask&) = delete;

  const TaskSpec& spec() const override { return spec_; }
  const mjModel_* model() const override { return model_; }
  std::unique_ptr<TaskState> make_state() const override;
  void reset(TaskState& s, uint64_t seed, float* obs) const override;
  StepResult step(TaskState& s, const float* action, float* obs) const override;
  // success, time_s, path_m, collision, final_distance.
  void episode_metrics(const TaskState& s, float* out) const override;
  // From above, framing the robot with its goal (a red disc of the goal radius).
  void view(const TaskState& s, const mjData_* pose, int root, TaskView& out) const override;

  // Starts an episode on a given map (tests, tools).
  void reset_to(TaskState& s, const MobileMap& map, float* obs) const;

  BaseKind base() const { return robot_.base; }
  const config::MobileSceneConfig& scene() const { return robot_.scene; }
  const MapGenerator& maps() const { return *maps_; }
  const Lidar& lidar() const { return *lidar_; }
  // Base commands of the discrete action set, each (Vx, Vy, W) in m/s, m/s, rad/s.
  const std::vector<std::array<double, 3>>& discrete_commands() const { return commands_; }
  // The base command an action asks for; throws std::invalid_argument on a discrete index out of
  // range.
  std::array<double, 3> base_command(const float* action) const;
  // Wheel speeds (rad/s) for a base command, through the paper's kinematics; the first
  // num_wheels() entries are used (Jetbot: left, right; Kaya: A, B, C).
  std::array<double, 3> wheel_speeds(const std::array<double, 3>& cmd) const;
  int num_wheels() const { return int(wheel_joints_.size()); }
  double wheel_radius() const { return wheel_radius_; }
  // Jetbot: distance between the wheels (R); Kaya: center to wheel (L).
  double wheel_offset() const { return wheel_offset_; }
  double robot_radius() const { return robot_radius_; }
  double control_dt() const;
  // Base pose and velocity in the world: x, y, yaw; vx, vy (base frame), w.
  void pose(const TaskState& s, double* x, double* y, double* yaw) const;
  void base_velocity(const TaskState& s, double* vx, double* vy, double* w) const;
  double wheel_speed(const TaskState& s, int i) const;

 private:
  void write_obs(MobileState& s, float* obs) const;
  bool touches_obstacle(const mjData* d) const;

  MobileRobotSpec robot_;
  TaskSpec spec_;
  mjModel_* model_ = nullptr;  // owned
  std::unique_ptr<MapGenerator> maps_;
  std::unique_ptr<Lidar> lidar_;
  std::vector<std::array<double, 3>> commands_;
  std::vector<int> wheel_joints_, wheel_qvel_, roller_qpos_;
  std::vector<int> obstacle_mocap_;  // per slot
  std::vector<uint8_t> robot_geom_, world_geom_;
  int root_qpos_ = 0, root_qvel_ = 0;
  double wheel_radius_ = 0, wheel_offset_ = 0, robot_radius_ = 0, wheel_max_ = 1;
};

std::unique_ptr<Task> make_jetbot_task(const config::TaskConfig& cfg);
std::unique_ptr<Task> make_kaya_task(const config::TaskConfig& cfg);

}  // namespace farm::robots::mobile
