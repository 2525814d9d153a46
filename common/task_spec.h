// What a task looks like from outside: its name, observation and action sizes, episode limit and
// metric names. Plain data, so the learner's algorithms and the wire code read it without MuJoCo.
// A task's spec from its config is robots::task_spec() (robots/task_specs.h).
#pragma once

#include <cmath>
#include <string>
#include <vector>

#include "farm_config.pb.h"

namespace farm::robots {

struct TaskSpec {
  std::string name;
  int obs_dim = 0;
  int act_dim = 0;                        // actions are in [-1, 1]; the task scales them
  int max_episode_steps = 0;              // truncation
  std::vector<std::string> metric_names;  // per-episode metrics, reported with every episode
  // > 0: discrete actions; act_dim is 1 and the action is the index, in [0, num_actions), as a
  // float. 0: continuous actions in [-1, 1].
  int num_actions = 0;
  // The most |reward| of one step can be, from the config: an evaluation answer whose return is
  // beyond length x reward_bound is refused (learner/eval_answer.h). Infinite: not declared.
  // tests/unit/test_task_conformance.cpp steps every task and holds its rewards to it.
  double reward_bound = HUGE_VAL;
  // The least and the most one step's reward can be, where the task knows a side (within
  // +-reward_bound): a task whose reward is never positive says reward_max 0, so that a return above
  // 0 is refused however short the episode. Infinite: that side not declared.
  double reward_min = -HUGE_VAL;
  double reward_max = HUGE_VAL;
};

// Whether an episode of `length` steps can have returned episode_return under a bound of
// reward_bound a step. The float sum over the episode may round a little past length x bound: a
// relative margin.
inline bool return_within_bound(double episode_return, double length, double reward_bound) {
  return std::abs(episode_return) <= length * reward_bound * (1 + 1e-4) + 1e-3;
}

// Whether an episode of `length` steps can have returned episode_return with each step's reward in
// [reward_min, reward_max] (infinite: that side not declared), with the same rounding margin.
inline bool return_within_range(double episode_return, double length, double reward_min, double reward_max) {
  if (std::isfinite(reward_max) && episode_return > length * reward_max + std::abs(length * reward_max) * 1e-4 + 1e-3)
    return false;
  if (std::isfinite(reward_min) && episode_return < length * reward_min - std::abs(length * reward_min) * 1e-4 - 1e-3)
    return false;
  return true;
}

}  // namespace farm::robots
