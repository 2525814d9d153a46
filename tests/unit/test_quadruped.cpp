// Quadrupeds of the MushroomRL paper (Unitree A1, Honey Badger, Silver Badger) on the legged layer: models
// stand, observation layout and scales, reward terms, command sampling and randomization ranges,
// on the real MuJoCo models. Contacts and falls: test_quadruped_contacts.cpp.
#include <gtest/gtest.h>
#include <mujoco/mujoco.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <string>
#include <vector>

#include "config.h"
#include "quadruped/legged.h"
#include "quadruped/quadruped_task.h"
#include "quadruped_testing.h"
#include "task.h"
#include "task_specs.h"

using namespace farm;
using namespace farm::robots;
using namespace farm::robots::quadruped;
using namespace farm::robots::quadruped::test_support;

TEST(Quadruped, EachModelStandsTenSecondsUnderTheDefaultPose) {
  for (const char* name : kRobots) {
    SCOPED_TRACE(name);
    auto task = quiet_task(name);
    auto s = task->make_state();
    std::vector<float> obs(task->spec().obs_dim), zero(task->spec().act_dim, 0.f);
    task->reset(*s, 1, obs.data());
    const auto& qs = static_cast<QuadrupedState&>(*s);
    double z0 = 0;
    const int steps = int(std::lround(10.0 / task->policy_dt()));
    for (int k = 0; k < steps; ++k) {
      const StepResult r = task->step(*s, zero.data(), obs.data());
      ASSERT_FALSE(r.terminated) << "fell at step " << k;
      double z, g[3];
      legged::read_property(qs.model, qs.data, legged::Property::kBodyHeight, task->trunk_body(), &z);
      legged::read_property(qs.model, qs.data, legged::Property::kProjectedGravity, task->trunk_body(), g);
      if (k == steps / 10) z0 = z;  // after settling
      ASSERT_LT(g[2], -0.95) << "tilted at step " << k;
      if (k > steps / 10) ASSERT_NEAR(z, z0, 0.05) << "trunk height drifted at step " << k;
    }
    for (float x : obs) ASSERT_TRUE(std::isfinite(x));
    // Standing still: the trunk height is the model's nominal one, in a sane range.
    EXPECT_GT(z0, 0.2);
    EXPECT_LT(z0, 0.45);
  }
}

TEST(Quadruped, ObservationLayoutAndScales) {
  for (const char* name : kRobots) {
    SCOPED_TRACE(name);
    auto task = quiet_task(name);
    const int n = task->num_joints();
    const bool badger = std::string(name) != "a1";
    EXPECT_EQ(n, std::string(name) == "silver_badger" ? 13 : 12);
    EXPECT_EQ(task->spec().act_dim, n);
    EXPECT_EQ(task->spec().obs_dim, 12 + 3 * n + (badger ? 1 + kNumDynamicsParams : 0));
    auto s = task->make_state();
    auto& qs = static_cast<QuadrupedState&>(*s);
    std::vector<float> obs(task->spec().obs_dim);
    task->reset(*s, 3, obs.data());
    // Set a known state: level trunk, base velocity (0.5, -0.2, 0.1) in its own frame, angular
    // (0.3, 0, -0.4), joints at default + 0.1 with velocity 2, a command; then observe it.
    const double v[3] = {0.5, -0.2, 0.1}, w[3] = {0.3, 0.0, -0.4};
    legged::write_property(qs.model, qs.data, legged::Property::kBodyLinVelLocal, task->trunk_body(), v);
    legged::write_property(qs.model, qs.data, legged::Property::kBodyAngVelLocal, task->trunk_body(), w);
    const auto& spec = task->obs_spec();
    for (int j = 0; j < n; ++j) {
      const double q = task->default_pose()[j] + 0.1, qd = 2.0;
      legged::write_property(qs.model, qs.data, legged::Property::kJointPos, spec.item("dof_pos").ids[j], &q);
      legged::write_property(qs.model, qs.data, legged::Property::kJointVel, spec.item("dof_vel").ids[j], &qd);
    }
    qs.command = {0.6, -0.4, 0.8};
    std::vector<std::vector<double>> custom = {{0.6, -0.4}, {0.8}, std::vector<double>(n, 0.25)};
    if (badger) custom.emplace_back(kNumDynamicsParams, 0.5);
    legged::build_observation(qs.model, qs.data, spec, custom, 0.0, qs.rng, obs.data());
    const auto& c = task->config();
    int i = 0;
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(obs[i++], v[k] * c.obs_lin_vel(), 1e-5) << "base_lin_vel " << k;
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(obs[i++], w[k] * c.obs_ang_vel(), 1e-5) << "base_ang_vel " << k;
    EXPECT_NEAR(obs[i++], 0.0, 1e-6);  // projected gravity of a level trunk
    EXPECT_NEAR(obs[i++], 0.0, 1e-6);
    EXPECT_NEAR(obs[i++], -1.0, 1e-6);
    EXPECT_NEAR(obs[i++], 0.6 * c.obs_lin_vel(), 1e-5);  // commands, legged_gym scales
    EXPECT_NEAR(obs[i++], -0.4 * c.obs_lin_vel(), 1e-5);
    EXPECT_NEAR(obs[i++], 0.8 * c.obs_ang_vel(), 1e-5);
    for (int j = 0; j < n; ++j) EXPECT_NEAR(obs[i++], 0.1 * c.obs_dof_pos(), 1e-5) << "dof_pos " << j;
    for (int j = 0; j < n; ++j) EXPECT_NEAR(obs[i++], 2.0 * c.obs_dof_vel(), 1e-5) << "dof_vel " << j;
    for (int j = 0; j < n; ++j) EXPECT_NEAR(obs[i++], 0.25, 1e-6) << "last_action " << j;
    if (badger) {
      double z;
      legged::read_property(qs.model, qs.data, legged::Property::kBodyHeight, task->trunk_body(), &z);
      EXPECT_NEAR(obs[i++], z * c.obs_height(), 1e-5);
      for (int k = 0; k < kNumDynamicsParams; ++k) EXPECT_NEAR(obs[i++], 0.5, 1e-6);
    }
    EXPECT_EQ(i, task->spec().obs_dim);
  }
}

TEST(Quadruped, ObservationNoiseStaysWithinItsBound) {
  config::TaskConfig c;
  c.set_name("a1");
  c.mutable_a1()->set_push_interval_s(0);
  auto t = make_task(c);
  auto& task = static_cast<QuadrupedTask&>(*t);
  auto s = task.make_state();
  auto& qs = static_cast<QuadrupedState&>(*s);
  std::vector<float> obs(task.spec().obs_dim), clean(task.spec().obs_dim);
  task.reset(*s, 5, obs.data());
  const int n = task.num_joints();
  std::vector<std::vector<double>> custom = {{0.1, 0.2}, {0.3}, std::vector<double>(n, 0.0)};
  legged::build_observation(qs.model, qs.data, task.obs_spec(), custom, 0.0, qs.rng, clean.data());
  double max_dv = 0;
  for (int k = 0; k < 200; ++k) {
    legged::build_observation(qs.model, qs.data, task.obs_spec(), custom, 1.0, qs.rng, obs.data());
    for (const auto& it : task.obs_spec().items()) {
      const double bound = it.property == legged::Property::kCustom ? it.noise : it.noise * it.scale;
      for (int i = it.start; i < it.start + it.size; ++i) {
        ASSERT_LE(std::abs(obs[i] - clean[i]), bound + 1e-5) << it.label;
        if (it.label == "dof_vel") max_dv = std::max(max_dv, double(std::abs(obs[i] - clean[i])));
      }
    }
  }
  // dof_vel noise is 1.5 * 0.05 = 0.075: 200 x 12 draws come near the bound.
  EXPECT_GT(max_dv, 0.06);
}

TEST(Quadruped, RewardTermsMatchHandComputedValues) {
  auto task = quiet_task("a1");
  auto s = task->make_state();
  auto& qs = static_cast<QuadrupedState&>(*s);
  std::vector<float> obs(task->spec().obs_dim);
  task->reset(*s, 7, obs.data());
  const double v[3] = {0.8, 0.1, 0.2}, w[3] = {0.3, -0.4, 0.5};
  legged::write_property(qs.model, qs.data, legged::Property::kBodyLinVelLocal, task->trunk_body(), v);
  legged::write_property(qs.model, qs.data, legged::Property::kBodyAngVelLocal, task->trunk_body(), w);
  qs.command = {1.0, 0.0, 0.25};
  const int n = task->num_joints();
  std::fill(qs.torques.begin(), qs.torques.end(), 2.0);
  std::fill(qs.last_action.begin(), qs.last_action.end(), 0.5);
  const auto& spec = task->obs_spec();
  for (int j = 0; j < n; ++j) {
    const double qd = qs.last_dof_vel[j] + 0.1;  // joint acceleration 0.1 / 0.02 = 5 rad/s^2
    legged::write_property(qs.model, qs.data, legged::Property::kJointVel, spec.item("dof_vel").ids[j], &qd);
  }
  // Calf 0 at -2.69653 (the A1 lower limit): past the 0.9 soft limit by 0.05 * 1.780232 = 0.0890116.
  const double calf = -2.69653;
  legged::write_property(qs.model, qs.data, legged::Property::kJointPos, spec.item("dof_pos").ids[2], &calf);
  std::vector<double> a(n, 1.5);
  qs.feet_air_time = {0.7, 0.0, 0.3, 0.0};
  const std::array<bool, 4> first = {true, false, true, false};
  const std::array<bool, 4> down = {true, true, false, false};  // filtered contacts, as step() passes them
  const RewardTerms t = task->reward_terms(qs, a, first, down);
  EXPECT_NEAR(t.tracking_lin_vel, std::exp(-(0.04 + 0.01) / 0.25), 1e-9);
  EXPECT_NEAR(t.tracking_ang_vel, std::exp(-0.0625 / 0.25), 1e-9);
  EXPECT_NEAR(t.lin_vel_z, 0.04, 1e-9);
  EXPECT_NEAR(t.ang_vel_xy, 0.25, 1e-9);
  EXPECT_NEAR(t.torques, 12 * 4.0, 1e-9);
  EXPECT_NEAR(t.dof_acc, 12 * 25.0, 1e-6);
  EXPECT_NEAR(t.action_rate, 12 * 1.0, 1e-9);
  EXPECT_NEAR(t.dof_pos_limits, 0.05 * (-0.916298 + 2.69653), 1e-6);
  EXPECT_NEAR(t.feet_air_time, (0.7 - 0.5) + (0.3 - 0.5), 1e-9);
  EXPECT_NEAR(t.feet_pair_off_ground, 1.0, 1e-12);  // rear pair in the air, front pair down
  // The contact filter (step() passes a foot as down if it touched on this step or the one
  // before): a foot down on the step before still counts as down (a trot's diagonal hand-over is
  // no pair in the air); both pairs up on two steps running count twice.
  // Raw {1, 0, 0, 1} after {0, 1, 1, 0}: all four down.
  EXPECT_EQ(task->reward_terms(qs, a, first, {true, true, true, true}).feet_pair_off_ground, 0.0);
  // Raw {0, 0, 0, 0} after {0, 0, 0, 0}: none down.
  EXPECT_EQ(task->reward_terms(qs, a, first, {false, false, false, false}).feet_pair_off_ground, 2.0);
  // Raw {1, 1, 0, 0} after {0, 0, 0, 1}: the rear pair is not both in the air.
  EXPECT_EQ(task->reward_terms(qs, a, first, {true, true, false, true}).feet_pair_off_ground, 0.0);
  EXPECT_NEAR(t.orientation, 0.0, 1e-12);
  const auto& w8 = task->config().reward();
  const double expected =
      (w8.tracking_lin_vel() * t.tracking_lin_vel + w8.tracking_ang_vel() * t.tracking_ang_vel + w8.lin_vel_z() * 0.04 +
       w8.ang_vel_xy() * 0.25 + w8.collision() * t.collision + w8.dof_pos_limits() * t.dof_pos_limits +
       w8.torques() * 48 + w8.dof_acc() * 300 + w8.action_rate() * 12 + w8.feet_air_time() * 0.0) *
      0.02;
  EXPECT_NEAR(task->total_reward(t), std::max(0.0, expected), 1e-9);
  // A1: no base-height or feet-pair terms; Badgers: both (MushroomRL paper §3.4).
  EXPECT_EQ(w8.base_height(), 0.0);
  EXPECT_LT(quiet_task("honey_badger")->config().reward().base_height(), 0.0);
  EXPECT_LT(quiet_task("silver_badger")->config().reward().feet_pair_off_ground(), 0.0);
  // Feet air time counts only while the robot is asked to move.
  qs.command = {0.0, 0.0, 0.5};
  EXPECT_EQ(task->reward_terms(qs, a, first, down).feet_air_time, 0.0);
}

TEST(Quadruped, OnlyPositiveRewardsClipsAtZero) {
  auto task = quiet_task("a1");
  RewardTerms t;
  t.lin_vel_z = 10.0;  // -2 * 10 * 0.02 < 0
  EXPECT_EQ(task->total_reward(t), 0.0);
  config::TaskConfig c;
  c.set_name("a1");
  c.mutable_a1()->set_only_positive_rewards(false);
  auto t2 = make_task(c);
  EXPECT_NEAR(static_cast<QuadrupedTask&>(*t2).total_reward(t), -2.0 * 10.0 * 0.02, 1e-12);
}

TEST(Quadruped, CommandSamplingStatistics) {
  auto task = quiet_task("a1");
  auto s = task->make_state();
  auto& qs = static_cast<QuadrupedState&>(*s);
  std::vector<float> obs(task->spec().obs_dim);
  task->reset(*s, 11, obs.data());
  const int N = 20000;
  int zeros_x = 0;
  double sum_x = 0, sum_heading = 0;
  for (int k = 0; k < N; ++k) {
    task->sample_command(qs);
    for (int i = 0; i < 2; ++i) {
      const double c = qs.command[i];
      ASSERT_LE(std::abs(c), 1.0);
      ASSERT_TRUE(c == 0.0 || std::abs(c) >= 0.2) << c;  // MushroomRL paper §3.3: |v| < 0.2 rounds to 0
    }
    ASSERT_LE(std::abs(qs.command[2]), 1.0);
    ASSERT_LE(std::abs(qs.heading_target), M_PI);
    zeros_x += qs.command[0] == 0.0;
    sum_x += qs.command[0];
    sum_heading += qs.heading_target;
  }
  // P(|U(-1, 1)| < 0.2) = 0.2; 20,000 draws: standard error 0.003.
  EXPECT_NEAR(double(zeros_x) / N, 0.2, 0.015);
  EXPECT_NEAR(sum_x / N, 0.0, 0.03);
  EXPECT_NEAR(sum_heading / N, 0.0, 0.1);
  // Heading: the yaw-rate command is gain * heading error, wrapped, clipped to +-1 rad/s.
  EXPECT_NEAR(task->heading_yaw_rate(0.4, 0.0), 0.2, 1e-12);
  EXPECT_NEAR(task->heading_yaw_rate(3.0, -3.0), 0.5 * (6.0 - 2 * M_PI), 1e-9);  // wraps the short way
  EXPECT_EQ(task->heading_yaw_rate(3.0, 0.0), 1.0);
  EXPECT_EQ(task->heading_yaw_rate(-3.0, 0.0), -1.0);
  // Badgers: the yaw rate is drawn directly, uniform over [-1, 1].
  auto hb = quiet_task("honey_badger");
  auto hs = hb->make_state();
  auto& hqs = static_cast<QuadrupedState&>(*hs);
  std::vector<float> hobs(hb->spec().obs_dim);
  hb->reset(*hs, 12, hobs.data());
  double sum_sq = 0;
  for (int k = 0; k < N; ++k) {
    hb->sample_command(hqs);
    sum_sq += hqs.command[2] * hqs.command[2];
  }
  EXPECT_NEAR(sum_sq / N, 1.0 / 3.0, 0.02);  // variance of U(-1, 1)
}

TEST(Quadruped, CommandsAreResampledAtTheConfiguredRate) {
  config::TaskConfig c;
  c.set_name("honey_badger");
  c.mutable_honey_badger()->set_command_resample_prob(0.05);
  auto t = make_task(c);
  auto& task = static_cast<QuadrupedTask&>(*t);
  auto s = task.make_state();
  auto& qs = static_cast<QuadrupedState&>(*s);
  std::vector<float> obs(task.spec().obs_dim), zero(task.spec().act_dim, 0.f);
  task.reset(*s, 13, obs.data());
  int changes = 0, steps = 0;
  for (int k = 0; k < 1200; ++k) {
    const auto before = qs.command;
    const StepResult r = task.step(*s, zero.data(), obs.data());
    if (r.terminated || r.truncated)
      task.reset(*s, 100 + k, obs.data());
    else {
      ++steps;
      changes += before[2] != qs.command[2];
    }
  }
  // 0.05 per step: about 60 of 1200, standard deviation 7.5.
  EXPECT_NEAR(double(changes) / steps, 0.05, 0.02);
}

TEST(Quadruped, RandomizationStaysWithinItsRanges) {
  for (const char* name : {"a1", "silver_badger"}) {
    SCOPED_TRACE(name);
    auto task = quiet_task(name, std::string(name) != "a1");
    const auto& c = task->config();
    const mjModel* nominal = task->model();
    auto s = task->make_state();
    auto& qs = static_cast<QuadrupedState&>(*s);
    std::vector<float> obs(task->spec().obs_dim);
    const int trunk = task->trunk_body();
    const int foot = task->feet().geoms[0];
    double lo_f = 1e9, hi_f = -1e9;
    for (int k = 0; k < 300; ++k) {
      task->reset(*s, 1000 + k, obs.data());
      const double f = qs.model->geom_friction[3 * foot];
      ASSERT_GE(f, c.friction_min());
      ASSERT_LE(f, c.friction_max());
      lo_f = std::min(lo_f, f);
      hi_f = std::max(hi_f, f);
      for (double p : qs.dynamics) ASSERT_LE(std::abs(p), 1.0);
      const double m = qs.model->body_mass[trunk], m0 = nominal->body_mass[trunk];
      if (c.randomize_dynamics()) {
        ASSERT_GE(m, m0 * (1 - c.trunk_mass_rel()) - 1e-12);
        ASSERT_LE(m, m0 * (1 + c.trunk_mass_rel()) + 1e-12);
        for (int a = 0; a < 3; ++a)
          ASSERT_LE(std::abs(qs.model->body_ipos[3 * trunk + a] - nominal->body_ipos[3 * trunk + a]),
                    c.com_shift() + 1e-12);
        ASSERT_GE(qs.kp, c.kp() * (1 - c.kp_rel()) - 1e-12);
        ASSERT_LE(qs.kp, c.kp() * (1 + c.kp_rel()) + 1e-12);
        ASSERT_LE(std::abs(qs.kd / c.kd() - 1), c.kd_rel() + 1e-12);
        ASSERT_LE(std::abs(qs.action_scale / c.action_scale() - 1), c.action_scale_rel() + 1e-12);
        ASSERT_LE(std::abs(qs.torque_multiplier - 1), c.torque_multiplier_rel() + 1e-12);
        ASSERT_LE(std::abs(qs.velocity_limit / c.velocity_limit() - 1), c.velocity_limit_rel() + 1e-12);
        ASSERT_LE(std::abs(qs.model->geom_size[3 * foot] / nominal->geom_size[3 * foot] - 1),
                  c.foot_size_rel() + 1e-12);
        for (int j = 0; j < nominal->njnt; ++j) {
          if (nominal->jnt_type[j] != mjJNT_HINGE) continue;
          const int dof = nominal->jnt_dofadr[j];
          ASSERT_GE(qs.model->dof_damping[dof], 0.0);
          ASSERT_LE(qs.model->dof_damping[dof], c.joint_damping_max() + 1e-12);
          ASSERT_LE(qs.model->jnt_stiffness[j], c.joint_stiffness_max() + 1e-12);
          ASSERT_GE(qs.model->dof_armature[dof], 0.005 - 1e-12);
          ASSERT_LE(qs.model->dof_armature[dof], c.armature_max() + 1e-12);
          ASSERT_LE(qs.model->dof_frictionloss[dof], c.frictionloss_max() + 1e-12);
        }
      } else {
        ASSERT_EQ(m, m0);  // the A1 randomizes friction, start pose and pushes only (MushroomRL paper §3.3)
        ASSERT_EQ(qs.kp, c.kp());
      }
    }
    // 300 draws spread over most of the range.
    EXPECT_LT(lo_f, c.friction_min() + 0.1);
    EXPECT_GT(hi_f, c.friction_max() - 0.1);
  }
  // Initial joint positions: default x U(0.5, 1.5), within the joint range.
  config::TaskConfig c;
  c.set_name("a1");
  auto t = make_task(c);
  auto& task = static_cast<QuadrupedTask&>(*t);
  auto s = task.make_state();
  auto& qs = static_cast<QuadrupedState&>(*s);
  std::vector<float> obs(task.spec().obs_dim);
  const auto& ids = task.obs_spec().item("dof_pos").ids;
  int lifted = 0;
  for (int k = 0; k < 100; ++k) {
    task.reset(*s, 5000 + k, obs.data());
    for (int j = 0; j < task.num_joints(); ++j) {
      double q;
      legged::read_property(qs.model, qs.data, legged::Property::kJointPos, ids[j], &q);
      const double d = task.default_pose()[j];
      const double lo = std::min(0.5 * d, 1.5 * d), hi = std::max(0.5 * d, 1.5 * d);
      ASSERT_GE(q, std::max(lo, qs.model->jnt_range[2 * ids[j]]) - 1e-9);
      ASSERT_LE(q, std::min(hi, qs.model->jnt_range[2 * ids[j] + 1]) + 1e-9);
    }
    // No foot starts inside the floor: the lowest one is init_foot_clearance above it, or higher.
    double lowest = 1e9;
    for (int g : task.feet().geoms)
      lowest = std::min(lowest, qs.data->geom_xpos[3 * g + 2] - qs.model->geom_size[3 * g]);
    ASSERT_GE(lowest, task.config().init_foot_clearance() - 1e-9);
    lifted += lowest < task.config().init_foot_clearance() + 1e-9;
  }
  EXPECT_GT(lifted, 10);  // many scaled poses reach below the default stance
}

TEST(Quadruped, BadConfigNamesTheField) {
  config::TaskConfig c;
  c.set_name("a1");
  c.mutable_a1()->set_decimation(0);
  try {
    make_task(c);
    FAIL() << "expected an error";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("decimation"), std::string::npos) << e.what();
  }
  c.mutable_a1()->set_decimation(4);
  c.mutable_a1()->set_friction_min(2.0);
  EXPECT_THROW(make_task(c), std::invalid_argument);
}

TEST(Quadruped, ShippedConfigsBuildTheirTasks) {
  for (const char* f : {"a1_ppo", "honey_badger_ppo", "silver_badger_ppo"}) {
    SCOPED_TRACE(f);
    const auto c = farm::robots::load_config_file(std::string(FARM_SOURCE_DIR) + "/deploy/configs/" + f + ".txtpb");
    EXPECT_EQ(c.algorithm(), "ppo");
    auto t = make_task(c.task());
    EXPECT_EQ(t->spec().act_dim, c.task().name() == "silver_badger" ? 13 : 12);
  }
}
