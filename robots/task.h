// The task interface every robot implements. A Task is what does not change while simulating
// (the MuJoCo model, constants from the config); a TaskState is where one episode is (mjData,
// RNG, counters). A worker holds one Task and N TaskStates.
#pragma once

#include <functional>
#include <memory>
#include <random>
#include <string>
#include <utility>
#include <vector>

#include "farm_config.pb.h"
#include "task_spec.h"

struct mjModel_;
struct mjData_;

namespace farm::robots {

struct TaskState {
  virtual ~TaskState();
  mjData_* data = nullptr;  // owned; freed by the destructor
  std::mt19937_64 rng;
  int step = 0;  // steps in the current episode
  double episode_return = 0.0;
  // Called after every physics step inside Task::step when set (farm-play draws its video frames
  // from it at the video's rate, not once per control step). Empty in workers and evaluations.
  std::function<void()> after_physics_step;
};

// What a viewer (farm-play) shows of an episode besides the model, as the task declares it: the
// camera's default elevation, a point to keep in the picture with the robot, markers for what the
// robot goes after, and overlay rows.
struct ViewMarker {
  enum Kind { kDisc, kArrow } kind = kDisc;
  double pos[3] = {0, 0, 0};  // the disc's centre, or the arrow's start (world)
  double to[3] = {0, 0, 0};   // the arrow's end
  double radius = 0;          // the disc's radius, or the arrow's width (m)
  double half_height = 0;     // the disc's half thickness (m)
  float rgba[4] = {0.9f, 0.1f, 0.1f, 0.7f};
};
struct TaskView {
  double elevation = -10;  // degrees: the camera's default, below the horizon when negative
  // A point the camera frames together with the robot (a goal), and the scene's half size that
  // bounds the camera's distance then; unused where frame_extent is 0.
  double frame_point[3] = {0, 0, 0};
  double frame_extent = 0;
  std::vector<ViewMarker> markers;
  std::vector<std::pair<std::string, std::string>> rows;
};

struct StepResult {
  float reward = 0.f;
  bool terminated = false;  // a true end (fall, goal): do not bootstrap
  bool truncated = false;   // time limit: bootstrap
};

class Task {
 public:
  virtual ~Task();
  virtual const TaskSpec& spec() const = 0;
  virtual const mjModel_* model() const = 0;
  // The model `s` simulates: model(), unless the state holds its own copy (a terrain, randomized
  // dynamics). What a renderer of that state draws with.
  virtual const mjModel_* model_of(const TaskState&) const { return model(); }
  virtual std::unique_ptr<TaskState> make_state() const = 0;
  // Starts an episode; writes obs_dim floats.
  virtual void reset(TaskState& s, uint64_t seed, float* obs) const = 0;
  // Conditions an evaluation spreads its episodes over evenly (mCLARI: its terrains), so that a
  // few episodes measure each of them rather than whichever reset draws: evaluation episode k
  // starts with reset_in_condition(.., k mod eval_conditions(), ..). 0: none, reset draws.
  virtual int eval_conditions() const { return 0; }
  virtual void reset_in_condition(TaskState& s, uint64_t seed, int /*condition*/, float* obs) const {
    reset(s, seed, obs);
  }
  // One agent step (may run several physics steps); writes the next observation.
  virtual StepResult step(TaskState& s, const float* action, float* obs) const = 0;
  // Writes metric_names.size() floats about the episode that just ended.
  virtual void episode_metrics(const TaskState& s, float* out) const;
  // What a viewer shows of state `s` at `pose` (its kinematics done); `root` is the body the
  // viewer follows. The default shows nothing but the model.
  virtual void view(const TaskState& s, const mjData_* pose, int root, TaskView& out) const;
};

// A model with a collision list (<contact> pairs) takes a contact's friction from its pair, fixed
// when the model was compiled. After its geoms' friction changes (randomization), pair `p` gets
// what MuJoCo mixes for a contact of its two geoms without the list: per component the larger of
// the two (sliding, sliding, torsional, rolling, rolling).
void mix_pair_friction(mjModel_* m, int p);

// A velocity command (vx, vy in the root's frame, yaw rate) shown as legged robots show it: a green
// arrow above the root, one second of the command turned to the world by the root's yaw, and an
// overlay row.
void command_view(const double command[3], const mjData_* pose, int root, TaskView& out);

// Builds the task named by cfg.name(); throws std::invalid_argument naming the known tasks.
std::unique_ptr<Task> make_task(const config::TaskConfig& cfg);
std::vector<std::string> task_names();

}  // namespace farm::robots
