// Cart-pole swing-up with the model and the reward of dm_control's cartpole "swingup": the pole
// starts hanging down, the agent pushes the cart; reward per step in [0, 1] is
// upright * centered * small_control * small_velocity. No termination; truncation at the time
// limit. Observation [x, cos th, sin th, xdot, thdot]; action [-1, 1] scaled by max_force.
#pragma once

#include <memory>

#include "task.h"

namespace farm::robots {

struct CartpoleState : TaskState {
  int upright_steps = 0;  // steps that ended with cos(th) > kUprightCos
};

class CartpoleTask final : public Task {
 public:
  static constexpr double kUprightCos = 0.95;

  // Throws std::invalid_argument naming the config field that is out of range.
  explicit CartpoleTask(const config::CartpoleConfig& cfg);
  ~CartpoleTask() override;
  CartpoleTask(const CartpoleTask&) = delete;
  CartpoleTask& operator=(const CartpoleTask&) = delete;

  const TaskSpec& spec() const override { return spec_; }
  const mjModel_* model() const override { return model_; }
  std::unique_ptr<TaskState> make_state() const override;
  void reset(TaskState& s, uint64_t seed, float* obs) const override;
  StepResult step(TaskState& s, const float* action, float* obs) const override;
  // "upright_fraction": share of the episode's steps with cos(th) > kUprightCos.
  void episode_metrics(const TaskState& s, float* out) const override;

  // The dm_control swing-up reward of a state and a control in [-1, 1].
  static double reward(double x, double cos_th, double thdot, double control);

 private:
  void write_obs(const TaskState& s, float* obs) const;
  config::CartpoleConfig cfg_;
  TaskSpec spec_;
  mjModel_* model_ = nullptr;  // owned
};

namespace cartpole {
// Registered as "cartpole" (robots/tasks.def); reads cfg.cartpole().
std::unique_ptr<Task> make_cartpole_task(const config::TaskConfig& cfg);
}  // namespace cartpole

}  // namespace farm::robots
