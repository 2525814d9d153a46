// Pendulum swing-up with the dynamics, reward, reset and time limit of Gymnasium's
// Pendulum-v1, simulated by MuJoCo, so returns compare with published Pendulum-v1 results.
// Observation [cos th, sin th, thdot]; action [-1, 1] scaled to +-max_torque; th = 0 upright.
#pragma once

#include <memory>

#include "task.h"

namespace farm::robots {

struct PendulumState : TaskState {
  int upright_steps = 0;  // steps of this episode that ended with cos(th) > kUprightCos
};

class PendulumTask final : public Task {
 public:
  static constexpr double kUprightCos = 0.95;

  // Throws std::invalid_argument naming the config field that is out of range.
  explicit PendulumTask(const config::PendulumConfig& cfg);
  ~PendulumTask() override;
  PendulumTask(const PendulumTask&) = delete;
  PendulumTask& operator=(const PendulumTask&) = delete;

  const TaskSpec& spec() const override { return spec_; }
  const mjModel_* model() const override { return model_; }
  std::unique_ptr<TaskState> make_state() const override;
  void reset(TaskState& s, uint64_t seed, float* obs) const override;
  StepResult step(TaskState& s, const float* action, float* obs) const override;
  // metric "upright_fraction": upright_steps / steps of the episode.
  void episode_metrics(const TaskState& s, float* out) const override;

  const config::PendulumConfig& config() const { return cfg_; }
  // Puts the pendulum at (th, thdot) mid-episode and writes the observation (tests, demos).
  void set_state(TaskState& s, double th, double thdot, float* obs) const;
  static double angle(const TaskState& s);
  static double velocity(const TaskState& s);

 private:
  void write_obs(const TaskState& s, float* obs) const;

  config::PendulumConfig cfg_;
  TaskSpec spec_;
  mjModel_* model_ = nullptr;  // owned
};

namespace pendulum {
// Registered as "pendulum" (robots/tasks.def); reads cfg.pendulum() (Pendulum-v1 defaults where unset).
std::unique_ptr<Task> make_pendulum_task(const config::TaskConfig& cfg);
}  // namespace pendulum

}  // namespace farm::robots
