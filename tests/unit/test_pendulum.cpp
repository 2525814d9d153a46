#include <gtest/gtest.h>
#include <mujoco/mujoco.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <stdexcept>
#include <string>

#include "embedded_mjcf.h"
#include "pendulum/pendulum_task.h"
#include "task.h"

namespace farm::robots {
namespace {

// Gymnasium Pendulum-v1, transcribed, in double precision.
struct Reference {
  double g = 10, m = 1, l = 1, dt = 0.05, max_speed = 8, max_torque = 2;
  double th = 0, thdot = 0;
  static double angle_normalize(double x) {
    double r = std::fmod(x + M_PI, 2 * M_PI);
    if (r < 0) r += 2 * M_PI;
    return r - M_PI;
  }
  double step(double action) {  // returns the reward
    const double u = std::clamp(action * max_torque, -max_torque, max_torque);
    const double cost = std::pow(angle_normalize(th), 2) + 0.1 * thdot * thdot + 0.001 * u * u;
    double new_thdot = thdot + (3 * g / (2 * l) * std::sin(th) + 3.0 / (m * l * l) * u) * dt;
    new_thdot = std::clamp(new_thdot, -max_speed, max_speed);
    th = th + new_thdot * dt;
    thdot = new_thdot;
    return -cost;
  }
};

std::unique_ptr<PendulumTask> make(const config::PendulumConfig& c = {}) { return std::make_unique<PendulumTask>(c); }

TEST(Pendulum, SpecAndRegistry) {
  config::TaskConfig cfg;
  auto task = make_task(cfg);  // default name is "pendulum"
  const TaskSpec& s = task->spec();
  EXPECT_EQ(s.name, "pendulum");
  EXPECT_EQ(s.obs_dim, 3);
  EXPECT_EQ(s.act_dim, 1);
  EXPECT_EQ(s.max_episode_steps, 200);
  ASSERT_EQ(s.metric_names.size(), 1u);
  EXPECT_EQ(s.metric_names[0], "upright_fraction");
  const auto names = task_names();
  EXPECT_NE(std::find(names.begin(), names.end(), "pendulum"), names.end());
}

TEST(Pendulum, UnknownTaskListsKnownTasks) {
  config::TaskConfig cfg;
  cfg.set_name("nope");
  try {
    make_task(cfg);
    FAIL() << "expected std::invalid_argument";
  } catch (const std::invalid_argument& e) {
    EXPECT_STREQ(e.what(),
                 "unknown task 'nope'; known tasks: pendulum, cartpole, jetbot, kaya, mclari, a1, honey_badger, "
                 "silver_badger, terms");
  }
}

TEST(Pendulum, EmbeddedModel) {
  bool found = false;
  for (const auto& f : embedded_mjcf()) found |= std::string(f.path) == "pendulum/pendulum.xml";
  EXPECT_TRUE(found);
  try {
    load_embedded_model("missing/robot.xml");
    FAIL() << "expected std::runtime_error";
  } catch (const std::runtime_error& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("missing/robot.xml"), std::string::npos) << msg;
    EXPECT_NE(msg.find("pendulum/pendulum.xml"), std::string::npos) << msg;
  }
  mjModel* m = load_embedded_model("pendulum/pendulum.xml");
  ASSERT_NE(m, nullptr);
  EXPECT_EQ(m->nq, 1);
  EXPECT_EQ(m->nu, 1);
  EXPECT_EQ(m->opt.integrator, mjINT_EULER);
  mj_deleteModel(m);
}

// Runs one step of `task` and of the reference from (th, thdot, action) and compares.
void expect_one_step_matches(const PendulumTask& task, Reference ref, double th, double thdot, float action) {
  auto s = task.make_state();
  float obs[3];
  task.reset(*s, 1, obs);
  task.set_state(*s, th, thdot, obs);
  ref.th = th;
  ref.thdot = thdot;
  const StepResult r = task.step(*s, &action, obs);
  const double ref_reward = ref.step(action);
  SCOPED_TRACE("th " + std::to_string(th) + " thdot " + std::to_string(thdot) + " a " + std::to_string(action));
  EXPECT_NEAR(obs[0], std::cos(ref.th), 1e-5);
  EXPECT_NEAR(obs[1], std::sin(ref.th), 1e-5);
  EXPECT_NEAR(obs[2], ref.thdot, 1e-5);
  EXPECT_NEAR(PendulumTask::angle(*s), ref.th, 1e-9);
  EXPECT_NEAR(PendulumTask::velocity(*s), ref.thdot, 1e-9);
  EXPECT_NEAR(r.reward, ref_reward, 1e-5 * std::max(1.0, std::abs(ref_reward)));
  EXPECT_FALSE(r.terminated);
}

TEST(Pendulum, OneStepMatchesPendulumV1) {
  auto task = make();
  Reference ref;
  std::mt19937_64 rng(42);
  std::uniform_real_distribution<double> th(-6.0, 6.0), thdot(-8.0, 8.0), a(-1.5, 1.5);
  for (int i = 0; i < 50; ++i) expect_one_step_matches(*task, ref, th(rng), thdot(rng), a(rng));
  // Velocity clipping (the new velocity would exceed max_speed) in both directions.
  expect_one_step_matches(*task, ref, M_PI / 2, 7.9, 1.f);
  expect_one_step_matches(*task, ref, -M_PI / 2, -7.9, -1.f);
  // Angles beyond +-pi are normalized in the cost only.
  expect_one_step_matches(*task, ref, 3 * M_PI + 0.2, 0.0, 0.f);
}

TEST(Pendulum, RewardFormula) {
  auto task = make();
  auto s = task->make_state();
  float obs[3];
  task->reset(*s, 3, obs);
  task->set_state(*s, 2 * M_PI + 0.5, -3.0, obs);  // normalized angle 0.5
  const float a = 0.25f;                           // u = 0.5
  const StepResult r = task->step(*s, &a, obs);
  EXPECT_NEAR(r.reward, -(0.25 + 0.1 * 9.0 + 0.001 * 0.25), 1e-6);
}

TEST(Pendulum, TrajectoryMatchesPendulumV1) {
  auto task = make();
  Reference ref;
  auto s = task->make_state();
  float obs[3];
  task->reset(*s, 9, obs);
  ref.th = PendulumTask::angle(*s);
  ref.thdot = PendulumTask::velocity(*s);
  std::mt19937_64 rng(4);
  std::uniform_real_distribution<float> a(-1.f, 1.f);
  double ret = 0;
  for (int t = 0; t < 200; ++t) {
    const float act = a(rng);
    const StepResult r = task->step(*s, &act, obs);
    ret += ref.step(act);
    ASSERT_NEAR(PendulumTask::angle(*s), ref.th, 1e-6) << "t " << t;
    ASSERT_NEAR(PendulumTask::velocity(*s), ref.thdot, 1e-6) << "t " << t;
    EXPECT_EQ(r.truncated, t == 199);
  }
  EXPECT_NEAR(s->episode_return, ret, 1e-6 * std::abs(ret));
  EXPECT_EQ(s->step, 200);
}

TEST(Pendulum, TruncatesAtMaxEpisodeSteps) {
  auto task = make();
  auto s = task->make_state();
  float obs[3];
  const float a = 0.f;
  for (int episode = 0; episode < 2; ++episode) {
    task->reset(*s, 5 + episode, obs);
    EXPECT_EQ(s->step, 0);
    EXPECT_EQ(s->episode_return, 0.0);
    for (int t = 1; t <= 200; ++t) {
      const StepResult r = task->step(*s, &a, obs);
      ASSERT_FALSE(r.terminated);
      ASSERT_EQ(r.truncated, t == 200) << "t " << t;
    }
  }
  config::PendulumConfig short_cfg;
  short_cfg.set_max_episode_steps(3);
  auto short_task = make(short_cfg);
  auto s2 = short_task->make_state();
  short_task->reset(*s2, 1, obs);
  EXPECT_FALSE(short_task->step(*s2, &a, obs).truncated);
  EXPECT_FALSE(short_task->step(*s2, &a, obs).truncated);
  EXPECT_TRUE(short_task->step(*s2, &a, obs).truncated);
}

TEST(Pendulum, ResetRangesAndSeeding) {
  auto task = make();
  auto s = task->make_state();
  float obs[3];
  double th_min = 10, th_max = -10, v_min = 10, v_max = -10;
  for (uint64_t seed = 0; seed < 2000; ++seed) {
    task->reset(*s, seed, obs);
    const double th = PendulumTask::angle(*s), v = PendulumTask::velocity(*s);
    ASSERT_GE(th, -M_PI);
    ASSERT_LE(th, M_PI);
    ASSERT_GE(v, -1.0);
    ASSERT_LE(v, 1.0);
    ASSERT_NEAR(obs[0], std::cos(th), 1e-6);
    ASSERT_NEAR(obs[1], std::sin(th), 1e-6);
    ASSERT_NEAR(obs[2], v, 1e-6);
    th_min = std::min(th_min, th);
    th_max = std::max(th_max, th);
    v_min = std::min(v_min, v);
    v_max = std::max(v_max, v);
  }
  EXPECT_LT(th_min, -3.0);
  EXPECT_GT(th_max, 3.0);
  EXPECT_LT(v_min, -0.95);
  EXPECT_GT(v_max, 0.95);

  float a[3], b[3], c[3];
  task->reset(*s, 77, a);
  task->reset(*s, 78, c);
  task->reset(*s, 77, b);
  EXPECT_EQ(std::vector<float>(a, a + 3), std::vector<float>(b, b + 3));
  EXPECT_NE(std::vector<float>(a, a + 3), std::vector<float>(c, c + 3));

  config::PendulumConfig wide;
  wide.set_init_max_speed(5.0);
  auto wide_task = make(wide);
  auto s2 = wide_task->make_state();
  double vmax = 0;
  for (uint64_t seed = 0; seed < 500; ++seed) {
    wide_task->reset(*s2, seed, obs);
    vmax = std::max(vmax, std::abs(PendulumTask::velocity(*s2)));
  }
  EXPECT_GT(vmax, 4.5);
  EXPECT_LE(vmax, 5.0);
}

TEST(Pendulum, ConfigFieldsChangeTheDynamics) {
  config::PendulumConfig c;
  c.set_gravity(9.81);
  c.set_mass(2.0);
  c.set_length(0.5);
  c.set_dt(0.02);
  c.set_max_speed(5.0);
  c.set_max_torque(3.0);
  auto task = make(c);
  EXPECT_DOUBLE_EQ(task->model()->opt.timestep, 0.02);
  EXPECT_DOUBLE_EQ(task->model()->opt.gravity[2], -9.81);
  EXPECT_DOUBLE_EQ(task->model()->body_mass[1], 2.0);
  Reference ref;
  ref.g = 9.81;
  ref.m = 2.0;
  ref.l = 0.5;
  ref.dt = 0.02;
  ref.max_speed = 5.0;
  ref.max_torque = 3.0;
  std::mt19937_64 rng(8);
  std::uniform_real_distribution<double> th(-4.0, 4.0), thdot(-5.0, 5.0), a(-1.2, 1.2);
  for (int i = 0; i < 20; ++i) expect_one_step_matches(*task, ref, th(rng), thdot(rng), a(rng));
  expect_one_step_matches(*task, ref, 1.0, 4.9, 1.f);  // clipped at the new max_speed

  // Gravity alone: from horizontal at rest, one step gives thdot = 3 g / (2 l) dt.
  for (double g : {10.0, 20.0}) {
    config::PendulumConfig gc;
    gc.set_gravity(g);
    auto gt = make(gc);
    auto s = gt->make_state();
    float obs[3];
    gt->reset(*s, 1, obs);
    gt->set_state(*s, M_PI / 2, 0.0, obs);
    const float zero = 0.f;
    gt->step(*s, &zero, obs);
    EXPECT_NEAR(obs[2], 1.5 * g * 0.05, 1e-5) << "g " << g;
  }
}

TEST(Pendulum, RejectsBadConfig) {
  config::PendulumConfig c;
  c.set_length(-1.0);
  try {
    PendulumTask task(c);
    FAIL() << "expected std::invalid_argument";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("length"), std::string::npos) << e.what();
  }
  config::PendulumConfig c2;
  c2.set_max_episode_steps(0);
  EXPECT_THROW(PendulumTask{c2}, std::invalid_argument);
}

TEST(Pendulum, UprightFraction) {
  auto task = make();
  auto s = task->make_state();
  float obs[3], metric = -1.f;
  const float zero = 0.f;
  // Exactly upright at rest is an equilibrium: every step counts.
  task->reset(*s, 1, obs);
  task->set_state(*s, 0.0, 0.0, obs);
  for (int t = 0; t < 200; ++t) task->step(*s, &zero, obs);
  task->episode_metrics(*s, &metric);
  EXPECT_FLOAT_EQ(metric, 1.f);
  // Hanging down never counts.
  task->reset(*s, 1, obs);
  task->set_state(*s, M_PI, 0.0, obs);
  for (int t = 0; t < 200; ++t) task->step(*s, &zero, obs);
  task->episode_metrics(*s, &metric);
  EXPECT_FLOAT_EQ(metric, 0.f);
  // Starting upright and falling: some but not all steps.
  task->reset(*s, 1, obs);
  task->set_state(*s, 0.05, 0.0, obs);
  for (int t = 0; t < 200; ++t) task->step(*s, &zero, obs);
  task->episode_metrics(*s, &metric);
  EXPECT_GT(metric, 0.f);
  EXPECT_LT(metric, 0.5f);
}

}  // namespace
}  // namespace farm::robots
