// Quadruped walking after velocity commands (MushroomRL paper §3.3-3.4) for the Unitree A1, Honey Badger
// and Silver Badger (robots/quadruped/*.xml), on the legged layer (legged.h).
//
// Action: one target per actuated joint, default pose + action_scale * action_range * a, turned into
// torques by a PD law on every one of `decimation` physics steps. Observation (in this order):
//   base_lin_vel (3, base frame)  base_ang_vel (3)  projected_gravity (3)  command_lin (2)
//   command_yaw (1)  dof_pos (n, minus the default pose)  dof_vel (n)  last_action (n)
//   Badgers also: base_height (1)  dynamics (16 randomized parameters, each mapped to [-1, 1]
//   over its range, with noise)
// Reward: the legged_gym terms the paper names (LeggedRewardScales), each times the policy step.
// Termination: the trunk touches the floor, the trunk falls below min_base_height, or the
// simulation diverges.
#pragma once

#include <array>
#include <memory>
#include <string>
#include <vector>

#include "quadruped/legged.h"
#include "task.h"

namespace farm::robots::quadruped {

enum class Robot { kA1, kHoneyBadger, kSilverBadger };

// The 16 randomized dynamics parameters the Badgers observe (MushroomRL paper §3.4), in order.
constexpr int kNumDynamicsParams = 16;

struct QuadrupedState : TaskState {
  mjModel_* model = nullptr;        // owned: this episode's randomized copy of the task's model
  std::array<double, 3> command{};  // vx, vy (m/s, base frame), yaw rate (rad/s)
  double heading_target = 0;
  std::vector<double> last_action, last_dof_vel, targets, torques;
  std::array<double, 4> feet_air_time{};
  std::array<bool, 4> last_contact{};
  // Randomized controller and limits (Badgers; the A1 keeps the nominal values).
  double kp = 0, kd = 0, action_scale = 0, torque_multiplier = 1, velocity_limit = 0;
  std::vector<double> torque_limit;
  std::array<double, kNumDynamicsParams> dynamics{};  // each in [-1, 1] over its range
  int push_every_steps = 0;
  // Scratch reused on every step (no allocation in the worker's step loop): the action in
  // legged_gym's units, the feet's contact forces, the custom observation slots.
  std::vector<double> action, foot_forces;
  std::vector<std::vector<double>> custom_obs;
  // Episode sums for the metrics.
  double sum_tracking_lin = 0, sum_tracking_ang = 0, sum_lin_error = 0;
  bool fell = false;
  ~QuadrupedState() override;
};

// One reward term per field of LeggedRewardScales, before scaling (tests compare them with hand
// computations).
struct RewardTerms {
  double tracking_lin_vel = 0, tracking_ang_vel = 0, lin_vel_z = 0, ang_vel_xy = 0, collision = 0, dof_pos_limits = 0,
         torques = 0, dof_acc = 0, action_rate = 0, feet_air_time = 0, base_height = 0, feet_pair_off_ground = 0,
         orientation = 0;
};

class QuadrupedTask final : public Task {
 public:
  static constexpr int kLegs = 4;

  // Throws std::invalid_argument naming the config field that cannot work.
  QuadrupedTask(Robot robot, const config::LeggedConfig& cfg);
  ~QuadrupedTask() override;
  QuadrupedTask(const QuadrupedTask&) = delete;
  QuadrupedTask& operator=(const QuadrupedTask&) = delete;

  const TaskSpec& spec() const override { return spec_; }
  const mjModel_* model() const override { return model_; }
  const mjModel_* model_of(const TaskState& s) const override;  // the episode's randomized copy
  std::unique_ptr<TaskState> make_state() const override;
  void reset(TaskState& s, uint64_t seed, float* obs) const override;
  StepResult step(TaskState& s, const float* action, float* obs) const override;
  // tracking_lin, tracking_ang (per-step means of the two tracking terms, each in [0, 1]),
  // lin_vel_error (mean planar speed error, m/s), fell (1 if the episode ended in a fall), time_s.
  void episode_metrics(const TaskState& s, float* out) const override;
  // The velocity command as a green arrow above the trunk, one second long, and as an overlay row.
  void view(const TaskState& s, const mjData_* pose, int root, TaskView& out) const override;

  // The config with the robot's defaults applied (what the task runs with).
  const config::LeggedConfig& config() const { return cfg_; }
  Robot robot() const { return robot_; }
  int num_joints() const { return int(joints_.size()); }
  const std::vector<double>& default_pose() const { return default_pose_; }
  const legged::ObsSpec& obs_spec() const { return obs_spec_; }
  const legged::CollisionGroup& feet() const { return feet_; }
  const legged::CollisionGroup& legs() const { return legs_; }  // thighs and calves
  const legged::CollisionGroup& trunk() const { return trunk_; }
  const legged::CollisionGroup& floor() const { return floor_; }
  int trunk_body() const { return trunk_body_; }

  // Draws a command as the paper does (§3.3: vx, vy ~ U(-max, max), each rounded to 0 below
  // small_command; heading ~ U(-pi, pi) or, for the Badgers, yaw rate ~ U(-max, max)).
  void sample_command(QuadrupedState& s) const;
  // The yaw-rate command from the heading error (A1), clipped to +-ang_vel_max.
  double heading_yaw_rate(double heading_target, double heading) const;
  // The unscaled reward terms of the state after a step (used by step(); public for tests).
  // first_contact: the feet touching down on this step; contact_filt: the feet counted as down
  // (legged_gym's one-step filter: touching on this step or the one before), both as step() has them.
  RewardTerms reward_terms(const QuadrupedState& s, const std::vector<double>& action_legged_gym,
                           const std::array<bool, 4>& first_contact, const std::array<bool, 4>& contact_filt) const;
  // The step reward from terms: sum of scale * term * policy dt, clipped at 0 if only_positive.
  double total_reward(const RewardTerms& t) const;
  double policy_dt() const { return cfg_.decimation() * cfg_.physics_dt(); }
  // A fall: the trunk or a hip housing touches the floor, or the trunk is below min_base_height
  // (contacts as of the last mj_forward / mj_step).
  bool fallen(const QuadrupedState& s) const;
  // Base heading (yaw) in the world, from the trunk's orientation.
  double heading(const QuadrupedState& s) const;

 private:
  void randomize(QuadrupedState& s) const;
  void write_obs(QuadrupedState& s, float* obs) const;
  void pd_control(QuadrupedState& s, mjData_* d) const;

  Robot robot_;
  config::LeggedConfig cfg_;
  TaskSpec spec_;
  mjModel_* model_ = nullptr;  // owned, nominal
  std::vector<int> joints_, dofs_, qpos_adr_, actuators_;
  std::vector<double> default_pose_, soft_lower_, soft_upper_, nominal_torque_limit_;
  int trunk_body_ = -1, rear_trunk_body_ = -1;
  std::vector<int> foot_geoms_;
  legged::CollisionGroup feet_, legs_, trunk_, floor_;
  legged::ObsSpec obs_spec_;
  std::vector<double> home_qpos_;
};

std::unique_ptr<Task> make_a1_task(const config::TaskConfig& cfg);
std::unique_ptr<Task> make_honey_badger_task(const config::TaskConfig& cfg);
std::unique_ptr<Task> make_silver_badger_task(const config::TaskConfig& cfg);

}  // namespace farm::robots::quadruped
