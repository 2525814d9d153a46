// Helpers shared by the quadruped unit tests (test_quadruped*.cpp).
#pragma once

#include <mujoco/mujoco.h>

#include <memory>
#include <stdexcept>
#include <string>

#include "embedded_mjcf.h"
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

// The embedded MJCF text of a robot ("quadruped/a1.xml").
inline std::string embedded_text(const std::string& path) {
  for (const auto& f : embedded_mjcf())
    if (path == f.path) return f.text;
  throw std::runtime_error("no embedded MJCF '" + path + "'");
}

// The MJCF without its collision list: the <contact> block and option collision="predefined"
// cut (docs/record/quadrupeds.md, "The A1's physics step"), every other line as shipped, i.e. the model
// as it was before the list, on MuJoCo's broad phase. Throws if the text has no such list, so a
// test cannot compare a model with itself.
inline std::string without_collision_list(std::string xml) {
  const std::string attribute = " collision=\"predefined\"";
  const auto option = xml.find("<option ");
  const auto option_end = xml.find('>', option);
  const auto at = option == std::string::npos ? option : xml.find(attribute, option);
  const auto begin = xml.rfind("<contact>");  // the element, after any comment that names it
  const auto end = xml.find("</contact>");
  if (at == std::string::npos || at > option_end || begin == std::string::npos || end == std::string::npos ||
      end < begin)
    throw std::runtime_error("the MJCF has no collision list (<contact> block and collision=\"predefined\") to cut");
  xml = xml.substr(0, begin) + xml.substr(end + std::string("</contact>").size());
  return xml.erase(at, attribute.size());
}

// Makes the task's state run on a copy of `m` (a model with the same bodies, joints and geoms as
// the task's own, e.g. the one without the collision list); the next reset starts an episode on it.
inline void use_model(const QuadrupedTask& task, QuadrupedState& s, const mjModel* m) {
  mj_deleteData(s.data);
  mj_deleteModel(s.model);
  s.model = mj_copyModel(nullptr, m);
  s.model->opt.timestep = task.model()->opt.timestep;
  s.data = mj_makeData(s.model);
}

}  // namespace farm::robots::quadruped::test_support
