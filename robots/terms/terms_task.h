// The task of terms (task name "terms"): any MuJoCo model, loaded from memory (the model files the
// config carries, through MuJoCo's virtual file system), driven and judged by the terms its config
// lists (robots/terms/terms.proto, the library in terms_library.cpp).
//
// Step: the action (clamped to [-1, 1]) sets the actuators or the PD targets, `control_substeps`
// physics steps run, the command may be resampled and the root pushed, then the reward terms are
// summed (weight * value; clipped at 0 with only_positive_rewards), the termination terms are asked
// and the observation terms write the next observation, each (value - offset) * scale, noised and
// clipped. Values are read after mj_step, as Gymnasium's MuJoCo environments read them.
#pragma once

#include <array>
#include <memory>
#include <vector>

#include "task.h"
#include "terms/mjcf_bundle.h"

namespace mu {
class Parser;
}

namespace farm::robots::terms {

struct TermsState : TaskState {
  mjModel_* model = nullptr;  // owned: this episode's randomized copy, or null (the task's model)
  std::vector<double> action, last_action, targets, last_qvel;
  std::array<double, 3> command{};  // vx, vy (m/s, root frame), yaw rate (rad/s)
  double heading_target = 0;        // heading commands: the yaw the robot is asked to face (rad)
  std::vector<double> xpos_before;  // every body's position before the step (world)
  std::vector<double> qpos_before;
  std::array<double, 3> com_before{};  // the centre of mass before the step, where a term reads it
  double start_x = 0;
  int push_every_steps = 0;
  bool ended_by_term = false;
  // Per reward term: episode sums of weight x value and of the value; feet air time and last
  // contacts where the term keeps them.
  std::vector<double> reward_sums, value_sums;
  std::vector<std::vector<double>> air_time;
  std::vector<std::vector<char>> last_contact;
  // Reward expressions: the quantities they read (expression_quantities' order) and their parsers.
  std::vector<double> quantities;
  std::vector<std::unique_ptr<mu::Parser>> parsers;
  std::vector<double> obs_raw;  // scratch: the observation before scale, noise and clip
  ~TermsState() override;
};

struct Bound;  // a config's terms bound to the model (terms_library.h)

class TermsTask final : public Task {
 public:
  // cfg.name() == "terms"; cfg.terms() checked by the loader (its model bundle is checked again
  // here, before MuJoCo reads it). Throws std::invalid_argument or ModelError naming what is wrong.
  explicit TermsTask(const config::TermsConfig& cfg);
  ~TermsTask() override;
  TermsTask(const TermsTask&) = delete;
  TermsTask& operator=(const TermsTask&) = delete;

  const TaskSpec& spec() const override { return spec_; }
  const mjModel_* model() const override { return model_; }
  const mjModel_* model_of(const TaskState& s) const override;
  std::unique_ptr<TaskState> make_state() const override;
  void reset(TaskState& s, uint64_t seed, float* obs) const override;
  StepResult step(TaskState& s, const float* action, float* obs) const override;
  void episode_metrics(const TaskState& s, float* out) const override;
  // A legged view; with commands, the command as an arrow and an overlay row.
  void view(const TaskState& s, const mjData_* pose, int root, TaskView& out) const override;

  const config::TermsConfig& config() const { return cfg_; }
  double agent_dt() const;
  int root_body() const { return root_; }
  const std::vector<double>& default_qpos() const { return default_qpos_; }

 private:
  void apply_action(TermsState& s, mjData_* d) const;
  void write_obs(TermsState& s, float* obs) const;
  void update_quantities(TermsState& s) const;
  void randomize_model(TermsState& s) const;
  void sample_command(TermsState& s) const;
  double heading_yaw_rate(const TermsState& s) const;

  config::TermsConfig cfg_;
  TaskSpec spec_;
  mjModel_* model_ = nullptr;  // owned
  ModelInfo info_;
  int root_ = 1;
  std::unique_ptr<Bound> bound_;
  std::vector<double> default_qpos_, default_qvel_;
  bool randomized_model_ = false;
  int root_free_dof_ = -1;   // the root's free joint's first dof (pushes), -1 without one
  int root_free_qpos_ = -1;  // and its first qpos entry
  std::vector<int> friction_geoms_, clear_geoms_, friction_pairs_;
  std::vector<int> scaled_joints_;  // hinge and slide joints (reset.joint_pos_scale_*)
};

std::unique_ptr<Task> make_terms_task(const config::TaskConfig& cfg);

// Compiles a bundle's model from memory, MuJoCo's virtual file system holding every file of the
// bundle (check_bundle() first: nothing falls back to the disk). The caller owns the model.
mjModel_* load_bundle(const config::TermsConfig& cfg);

}  // namespace farm::robots::terms
