// Cart-pole swing-up (robots/cartpole): dm_control's swing-up reward, the start hanging down, no
// termination however the pole or the cart goes, the upright-fraction metric and the config
// fields that shape the dynamics. The interface checks every task shares are in
// test_task_conformance.cpp.
#include <gtest/gtest.h>
#include <mujoco/mujoco.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include "cartpole/cartpole_task.h"
#include "task.h"

namespace farm::robots {
namespace {

std::unique_ptr<CartpoleTask> make(const config::CartpoleConfig& c = {}) { return std::make_unique<CartpoleTask>(c); }

// Puts the cart and the pole where a test wants them, at rest.
void place(const CartpoleTask& task, TaskState& s, double x, double th, float* obs) {
  task.reset(s, 1, obs);
  s.data->qpos[0] = x;
  s.data->qpos[1] = th;
  s.data->qvel[0] = 0;
  s.data->qvel[1] = 0;
  mj_forward(task.model(), s.data);
}

TEST(Cartpole, SpecAndModelFollowTheConfig) {
  config::TaskConfig tc;
  tc.set_name("cartpole");
  auto registered = make_task(tc);
  const TaskSpec& s = registered->spec();
  EXPECT_EQ(s.name, "cartpole");
  EXPECT_EQ(s.obs_dim, 5);
  EXPECT_EQ(s.act_dim, 1);
  EXPECT_EQ(s.num_actions, 0);
  EXPECT_EQ(s.max_episode_steps, 500);
  EXPECT_EQ(s.metric_names, std::vector<std::string>{"upright_fraction"});
  EXPECT_DOUBLE_EQ(registered->model()->opt.timestep, 0.01);
  EXPECT_DOUBLE_EQ(registered->model()->actuator_gear[0], 10.0);  // dm_control: gear 10, force 1

  config::CartpoleConfig c;
  c.set_physics_dt(0.02);
  c.set_max_force(2.0);
  c.set_rail_limit(1.0);
  c.set_max_episode_steps(7);
  auto task = make(c);
  EXPECT_DOUBLE_EQ(task->model()->opt.timestep, 0.02);
  EXPECT_DOUBLE_EQ(task->model()->actuator_gear[0], 20.0);
  EXPECT_DOUBLE_EQ(task->model()->jnt_range[0], -1.0);
  EXPECT_DOUBLE_EQ(task->model()->jnt_range[1], 1.0);
  EXPECT_EQ(task->spec().max_episode_steps, 7);
}

TEST(Cartpole, StartsHangingDownNearTheCentre) {
  auto task = make();
  auto s = task->make_state();
  float obs[5];
  double spread = 0;
  for (uint64_t seed = 0; seed < 500; ++seed) {
    task->reset(*s, seed, obs);
    const double x = s->data->qpos[0], th = s->data->qpos[1];
    // N(0, 0.01) on each of x, th - pi, xdot, thdot: 6 sigma is never reached in 500 draws.
    ASSERT_LT(std::abs(x), 0.06);
    ASSERT_LT(std::abs(th - M_PI), 0.06);
    ASSERT_LT(std::abs(s->data->qvel[0]), 0.06);
    ASSERT_LT(std::abs(s->data->qvel[1]), 0.06);
    spread = std::max(spread, std::abs(x));
    // Observation [x, cos th, sin th, xdot, thdot].
    ASSERT_FLOAT_EQ(obs[0], float(x));
    ASSERT_FLOAT_EQ(obs[1], float(std::cos(th)));
    ASSERT_FLOAT_EQ(obs[2], float(std::sin(th)));
    ASSERT_FLOAT_EQ(obs[3], float(s->data->qvel[0]));
    ASSERT_FLOAT_EQ(obs[4], float(s->data->qvel[1]));
    ASSERT_LT(obs[1], -0.99f);
  }
  EXPECT_GT(spread, 0.02);  // the noise is there: 2 sigma is passed in 500 draws
  config::CartpoleConfig quiet;
  quiet.set_init_noise(0);
  auto exact = make(quiet);
  exact->reset(*s, 3, obs);
  EXPECT_EQ(s->data->qpos[0], 0.0);
  EXPECT_EQ(s->data->qpos[1], M_PI);
  EXPECT_EQ(obs[1], -1.f);
}

TEST(Cartpole, RewardIsDmControlSwingUp) {
  // upright (cos + 1) / 2, centered (1 + tol(x, 2)) / 2, small_control (4 + 1 - u^2) / 5,
  // small_velocity (1 + tol(thdot, 5)) / 2, where tol is 0.1 at the margin.
  EXPECT_DOUBLE_EQ(CartpoleTask::reward(0, 1, 0, 0), 1.0);
  EXPECT_DOUBLE_EQ(CartpoleTask::reward(0, -1, 0, 0), 0.0);
  EXPECT_DOUBLE_EQ(CartpoleTask::reward(0, 0, 0, 0), 0.5);
  EXPECT_NEAR(CartpoleTask::reward(2, 1, 0, 0), 0.55, 1e-12);
  EXPECT_NEAR(CartpoleTask::reward(-2, 1, 0, 0), 0.55, 1e-12);
  EXPECT_NEAR(CartpoleTask::reward(0, 1, 5, 0), 0.55, 1e-12);
  EXPECT_NEAR(CartpoleTask::reward(0, 1, 0, 1), 0.8, 1e-12);
  EXPECT_NEAR(CartpoleTask::reward(0, 1, 0, 0.5), 0.95, 1e-12);
  EXPECT_NEAR(CartpoleTask::reward(0, 1, 0, 3), 0.8, 1e-12);  // the control term bottoms out
  EXPECT_NEAR(CartpoleTask::reward(2, 0, 5, -1), 0.5 * 0.55 * 0.8 * 0.55, 1e-12);

  // The step's reward is that of the state it reaches and the clipped control, in [0, 1].
  auto task = make();
  auto s = task->make_state();
  float obs[5];
  task->reset(*s, 4, obs);
  for (float a : {0.3f, -1.f, 2.5f, 0.f, -0.8f}) {
    const StepResult r = task->step(*s, &a, obs);
    const double u = std::clamp(double(a), -1.0, 1.0);
    EXPECT_NEAR(r.reward, CartpoleTask::reward(s->data->qpos[0], std::cos(s->data->qpos[1]), s->data->qvel[1], u), 1e-6)
        << "action " << a;
    EXPECT_GE(r.reward, 0.f);
    EXPECT_LE(r.reward, 1.f);
  }
}

// The swing-up has no fall: a cart pushed into the end of its rail, or a pole dropped from
// horizontal there, goes on to the time limit; the rail's limit holds the cart.
TEST(Cartpole, NeverTerminatesAndTheRailHoldsTheCart) {
  auto task = make();
  auto s = task->make_state();
  float obs[5];
  for (float push : {1.f, -1.f, 0.f}) {
    if (push != 0.f) {
      task->reset(*s, 2, obs);
    } else {
      place(*task, *s, 1.7, M_PI / 2, obs);
    }
    double far = 0;
    for (int t = 1; t <= 500; ++t) {
      const StepResult r = task->step(*s, &push, obs);
      ASSERT_FALSE(r.terminated) << "push " << push << ", step " << t;
      ASSERT_EQ(r.truncated, t == 500) << "push " << push << ", step " << t;
      far = std::max(far, std::abs(s->data->qpos[0]));
    }
    EXPECT_EQ(s->step, 500);
    if (push == 0.f) continue;
    EXPECT_GT(far, 1.7) << "push " << push << ": the cart reaches the end of the rail";
    // The limit is soft (solreflimit 0.08 s): the full 10 N holds the cart some 0.17 m into it.
    EXPECT_LT(far, 2.0) << "push " << push;
  }
}

TEST(Cartpole, UprightFraction) {
  config::CartpoleConfig c;
  c.set_init_noise(0);
  auto task = make(c);
  auto s = task->make_state();
  float obs[5], metric = -1.f;
  const float zero = 0.f;
  // Exactly upright at rest, centred: an equilibrium paying the full reward on every step.
  place(*task, *s, 0.0, 0.0, obs);
  for (int t = 0; t < 500; ++t) EXPECT_FLOAT_EQ(task->step(*s, &zero, obs).reward, 1.f);
  task->episode_metrics(*s, &metric);
  EXPECT_FLOAT_EQ(metric, 1.f);
  EXPECT_NEAR(s->episode_return, 500.0, 1e-9);
  // Hanging down never counts, and pays nothing.
  task->reset(*s, 1, obs);
  for (int t = 0; t < 500; ++t) task->step(*s, &zero, obs);
  task->episode_metrics(*s, &metric);
  EXPECT_FLOAT_EQ(metric, 0.f);
  EXPECT_NEAR(s->episode_return, 0.0, 1e-6);
  // Starting just inside the upright band and falling: some steps, not most.
  place(*task, *s, 0.0, 0.25, obs);
  ASSERT_GT(std::cos(0.25), CartpoleTask::kUprightCos);
  for (int t = 0; t < 500; ++t) task->step(*s, &zero, obs);
  task->episode_metrics(*s, &metric);
  EXPECT_GT(metric, 0.f);
  EXPECT_LT(metric, 0.5f);
  // Before any step there is no fraction to take: 0, not a division by zero.
  task->reset(*s, 1, obs);
  task->episode_metrics(*s, &metric);
  EXPECT_EQ(metric, 0.f);
}

TEST(Cartpole, ConfigFieldsChangeTheDynamics) {
  // max_force scales the push: from a hanging pole at rest, one step's cart speed doubles with it.
  config::CartpoleConfig c;
  c.set_init_noise(0);
  double speed[2];
  for (int k = 0; k < 2; ++k) {
    c.set_max_force(k + 1.0);
    auto task = make(c);
    auto s = task->make_state();
    float obs[5];
    const float push = 1.f;
    task->reset(*s, 1, obs);
    task->step(*s, &push, obs);
    speed[k] = s->data->qvel[0];
  }
  EXPECT_GT(speed[0], 0.0);
  EXPECT_NEAR(speed[1] / speed[0], 2.0, 1e-3);

  // control_substeps: one agent step of two physics steps is two agent steps of one.
  config::CartpoleConfig one, two;
  two.set_control_substeps(2);
  auto t1 = make(one), t2 = make(two);
  auto s1 = t1->make_state(), s2 = t2->make_state();
  float o1[5], o2[5];
  t1->reset(*s1, 6, o1);
  t2->reset(*s2, 6, o2);
  for (float a : {0.7f, -0.2f, 1.f}) {
    t1->step(*s1, &a, o1);
    t1->step(*s1, &a, o1);
    t2->step(*s2, &a, o2);
    EXPECT_EQ(std::memcmp(o1, o2, sizeof o1), 0) << "action " << a;
  }
  EXPECT_EQ(s2->step, 3);

  // max_episode_steps: the time limit.
  config::CartpoleConfig short_cfg;
  short_cfg.set_max_episode_steps(3);
  auto t3 = make(short_cfg);
  auto s3 = t3->make_state();
  const float zero = 0.f;
  t3->reset(*s3, 1, o1);
  EXPECT_FALSE(t3->step(*s3, &zero, o1).truncated);
  EXPECT_FALSE(t3->step(*s3, &zero, o1).truncated);
  EXPECT_TRUE(t3->step(*s3, &zero, o1).truncated);
}

}  // namespace
}  // namespace farm::robots
