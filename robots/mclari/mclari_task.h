// The mCLARI microbot task of the mCLARI thesis §4: each of the 8 actuators is driven by
// V sin(2 pi f t + phi); the agent picks the frequency (f <- f + a0 df, integer, clamped) and the
// inter-leg phase group (a1 scaled to an index). One agent step is 1 s of simulated time at a
// timestep of 1 / (500 f); actuator power |tau omega| is sampled every 2 ms.
// Observation: [sum of mean |P_i|, mean speed of the centre of mass over the step, x error,
// y error to the target], each divided by its McLariConfig scale.
// Reward: efficiency eta = m g v / sum mean |P_i| (SI units), +10 and the end on reaching the
// target, -100 and the end on a fall or on leaving the ground; 180 steps per episode.
#pragma once

#include <array>
#include <memory>
#include <vector>

#include "task.h"

namespace farm::robots {

// What one agent step measured (SI units unless named otherwise).
struct McLariStepFigures {
  int frequency = 0;
  int group = 0;                           // of all 27
  std::array<double, 8> mean_abs_power{};  // W, per actuator
  double power = 0;                        // W, sum of mean |P_i|
  double speed_mm_s = 0;                   // |delta com_xy| / step time
  double efficiency = 0;                   // eta of the mCLARI thesis eq. 5.1
  int physics_steps = 0;
  int power_samples = 0;
  bool unstable = false;  // the simulation produced a non-finite state or a warning
};

struct McLariState : TaskState {
  ~McLariState() override;
  mjModel_* model = nullptr;  // owned copy of the terrain's model: the timestep follows f
  int terrain = 0;
  int frequency = 1;
  int group_index = 0;        // index into the active group set
  double phase = 0;           // 2 pi f t, accumulated so the drive stays continuous when f changes
  double target[2] = {0, 0};  // mm
  McLariStepFigures last;
  double efficiency_sum = 0, frequency_sum = 0;
  int measured_steps = 0;  // steps that ended without a fall
  bool fell = false, reached = false;
};

class McLariTask final : public Task {
 public:
  // Throws std::invalid_argument naming the McLariConfig field that is out of range.
  explicit McLariTask(const config::MclariConfig& cfg);
  ~McLariTask() override;
  McLariTask(const McLariTask&) = delete;
  McLariTask& operator=(const McLariTask&) = delete;

  const TaskSpec& spec() const override { return spec_; }
  const mjModel_* model() const override { return terrain_models_[0]; }
  const mjModel_* model_of(const TaskState& s) const override;  // the state's copy of its terrain
  const mjModel_* terrain_model(int terrain) const { return terrain_models_.at(terrain); }
  std::unique_ptr<TaskState> make_state() const override;
  void reset(TaskState& s, uint64_t seed, float* obs) const override;
  // An evaluation's episodes go round the config's terrains (each once, in their order).
  int eval_conditions() const override { return int(eval_terrains_.size()); }
  void reset_in_condition(TaskState& s, uint64_t seed, int condition, float* obs) const override;
  StepResult step(TaskState& s, const float* action, float* obs) const override;
  // "efficiency" (mean eta over the steps without a fall), "fell", "reached", "terrain",
  // "mean_frequency", "final_distance" (mm), "share" (efficiency over the terrain's
  // goal_efficiency, else its reference_efficiency, else 1; 0 after a fall).
  void episode_metrics(const TaskState& s, float* out) const override;
  // The target as a red disc of the radius that counts as reached; the terrain and gait as rows.
  void view(const TaskState& s, const mjData_* pose, int root, TaskView& out) const override;

  const config::MclariConfig& config() const { return cfg_; }
  const std::vector<float>& height_field() const { return hfield_; }
  const std::vector<int>& active_groups() const { return groups_; }
  // Starts an episode on this terrain (reset draws one from the config's list).
  void reset_on(TaskState& s, uint64_t seed, int terrain, float* obs) const;
  // Centre of mass of the robot (mm).
  static std::array<double, 3> com(const TaskState& s);
  double robot_mass() const { return mass_g_; }  // g

  // The pieces of the step, exposed for tests.
  static int next_frequency(int f, float a0, double df, int fmin, int fmax);
  static int group_index_from_action(float a1, int n);
  // m g v / P with m in g, v in mm/s, P in W; 0 when P <= 0.
  static double efficiency(double mass_g, double g_si, double speed_mm_s, double power_w);
  // Mean of |tau_k omega_k| over samples, converted from g mm^2 / s^3 to W.
  static double mean_abs_power_w(const double* torque, const double* omega, int samples);
  // Generalized force of the one-sided tendon springs at the current tendon lengths.
  void apply_tendon_springs(const mjModel_* m, mjData_* d) const;
  double ground_height(double x, double y, int terrain) const;  // mm

 private:
  void write_obs(const McLariState& s, float* obs) const;

  config::MclariConfig cfg_;
  TaskSpec spec_;
  std::vector<mjModel_*> terrain_models_;  // owned, one per terrain
  std::vector<float> hfield_;
  std::vector<int> groups_;         // active set, of all 27
  std::vector<int> frequencies_;    // a0 picks one of these when set (Hz)
  std::vector<int> terrains_;       // drawn at reset
  std::vector<int> eval_terrains_;  // terrains_ without repeats, in order
  int body_ = 1;                    // the robot's root body
  int act_dof_[8] = {};             // dof driven by actuator k
  double mass_g_ = 0;
};

namespace mclari {
// Registered as "mclari" (robots/tasks.def); reads cfg.mclari() (mCLARI thesis defaults where unset).
std::unique_ptr<Task> make_mclari_task(const config::TaskConfig& cfg);
}  // namespace mclari

}  // namespace farm::robots
