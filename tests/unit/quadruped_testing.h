// Helpers shared by the quadruped unit tests (test_quadruped*.cpp).
#pragma once

#include <memory>
#include <string>

#include "quadruped/quadruped_task.h"
#include "task.h"

namespace farm::robots::quadruped::test_support {

inline constexpr const char* kRobots[] = {"a1", "honey_badger", "silver_badger"};

inline config::LeggedConfig* legged_of(config::TaskConfig& c) {
  if (c.name() == "a1") return c.mutable_a1();
  if (c.name() == "honey_badger") return c.mutable_honey_badger();
  return c.mutable_silver_badger();
}

// A task with no noise, no pushes and no random start, so a state is what the test sets.
inline std::unique_ptr<QuadrupedTask> quiet_task(const std::string& name, bool randomize = false) {
  config::TaskConfig c;
  c.set_name(name);
  auto* l = legged_of(c);
  l->set_noise_level(0);
  l->set_push_interval_s(0);
  l->set_init_joint_scale_min(1);
  l->set_init_joint_scale_max(1);
  l->set_init_base_vel(0);
  l->set_randomize_dynamics(randomize);
  auto t = make_task(c);
  return std::unique_ptr<QuadrupedTask>(static_cast<QuadrupedTask*>(t.release()));
}

}  // namespace farm::robots::quadruped::test_support
