// mCLARI microbot (mCLARI thesis): model constants, stability, phase groups, the power / speed /
// efficiency computations, the height-field generator, reward and termination. The gait the
// action picks and the observation of gait and terrain: test_mclari_gait.cpp.
#include <gtest/gtest.h>
#include <mujoco/mujoco.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "mclari/mclari_task.h"
#include "mclari/phase_groups.h"
#include "mclari/terrain.h"
#include "task.h"

using farm::robots::McLariState;
using farm::robots::McLariTask;
namespace mclari = farm::robots::mclari;

namespace {

constexpr double kPi = 3.14159265358979323846;

farm::config::MclariConfig fixed(int f, int group) {
  farm::config::MclariConfig c;
  c.set_fixed_frequency(f);
  c.set_fixed_group(group);
  return c;
}

McLariState& st(farm::robots::TaskState& s) { return static_cast<McLariState&>(s); }

}  // namespace

TEST(McLari, ModelHasTheSeedConstants) {
  McLariTask task(farm::config::MclariConfig{});
  const mjModel* m = task.model();
  EXPECT_NEAR(task.robot_mass(), 0.96, 1e-9);    // mCLARI thesis §1.2
  EXPECT_DOUBLE_EQ(m->opt.gravity[2], -9810.0);  // mm/s^2
  EXPECT_EQ(m->nu, 8);
  EXPECT_EQ(m->ntendon, 2);
  EXPECT_EQ(m->neq, 2);
  for (int a = 0; a < m->nu; ++a) EXPECT_DOUBLE_EQ(m->actuator_gear[6 * a], 300.0);
  for (int leg = 0; leg < 4; ++leg) {
    for (const char* kind : {"lift", "swing"}) {
      const std::string name = kind + std::to_string(leg);
      const int j = mj_name2id(m, mjOBJ_JOINT, name.c_str());
      ASSERT_GE(j, 0) << name;
      EXPECT_EQ(m->jnt_type[j], mjJNT_HINGE);
      EXPECT_TRUE(m->jnt_limited[j]);
      EXPECT_NEAR(m->jnt_range[2 * j], -5 * kPi / 180, 1e-9);
      EXPECT_NEAR(m->jnt_range[2 * j + 1], 5 * kPi / 180, 1e-9);
      // springdamper="0.25 0.1": stiffness = M / (0.25 * 0.1)^2 = 1600 M and damping = 2 M / 0.25
      // = 8 M, i.e. H(s) = 1 / (s^2 + 8 s + 1600) per unit inertia (mCLARI thesis eq. 3.1). MuJoCo's
      // compiler takes M from its own inertia pass, within 1% of dof_M0.
      const int dof = m->jnt_dofadr[j];
      const double M = m->dof_M0[dof];
      EXPECT_NEAR(m->jnt_stiffness[j] / m->dof_damping[dof], 200.0, 1e-6) << name;
      EXPECT_NEAR(m->dof_damping[dof] / M, 8.0, 0.08) << name;
    }
  }
  EXPECT_NE(farm::robots::make_task([] {
              farm::config::TaskConfig c;
              c.set_name("mclari");
              return c;
            }()),
            nullptr);
}

// No NaN, no divergence and no fall over 30 s at 1 and 150 Hz on every terrain, with the
// simulation settings of deploy/configs/mclari_sac.txtpb (20 steps per period, timestep at most
// 2 ms); 1 s at 150 Hz with the thesis's 500 steps per period covers its finer timestep. Terrains
// are split over two threads to keep the test short; integration.mclari_policy runs 180 s
// episodes of a trained policy, mostly at 150 Hz, on every terrain.
TEST(McLari, StableThirtySecondsOnEveryTerrain) {
  struct Case {
    int terrain, f, spp, seconds;
  };
  std::vector<Case> cases;
  for (int terrain = 0; terrain < mclari::kNumTerrains; ++terrain) {
    cases.push_back({terrain, 1, 20, 30});
    cases.push_back({terrain, 150, 20, 30});
    cases.push_back({terrain, 150, 500, 1});
  }
  std::vector<std::string> failures(cases.size());
  std::vector<int> physics_steps(cases.size());
  auto run = [&](size_t begin) {
    for (size_t i = begin; i < cases.size(); i += 2) {
      const Case& c = cases[i];
      auto cfg = fixed(c.f, 19);
      cfg.set_steps_per_period(c.spp);
      cfg.set_max_timestep(0.002);
      McLariTask task(cfg);
      auto s = task.make_state();
      float obs[4], act[2] = {0, 0};
      task.reset_on(*s, 3, c.terrain, obs);
      for (int k = 0; k < c.seconds && failures[i].empty(); ++k) {
        const auto r = task.step(*s, act, obs);
        bool finite = std::isfinite(r.reward);
        for (float o : obs) finite = finite && std::isfinite(o);
        if (st(*s).last.unstable || r.terminated || !finite)
          failures[i] = std::string(mclari::terrain_name(c.terrain)) + " at " + std::to_string(c.f) + " Hz, " +
                        std::to_string(c.spp) + " steps/period: " +
                        (st(*s).last.unstable ? "unstable"
                         : r.terminated       ? "fell"
                                              : "non-finite") +
                        " in second " + std::to_string(k);
      }
      physics_steps[i] = st(*s).last.physics_steps;
    }
  };
  std::thread other(run, 1);
  run(0);
  other.join();
  for (size_t i = 0; i < cases.size(); ++i) {
    EXPECT_EQ(failures[i], "");
    // 1 / (spp f), capped at 2 ms: 500 steps at 1 Hz, 3000 at 150 Hz x 20, 75000 at 150 Hz x 500.
    const int expect = cases[i].f == 1 ? 500 : cases[i].f * cases[i].spp;
    EXPECT_EQ(physics_steps[i], expect);
  }
}

TEST(McLari, TwentySevenDistinctGroupsCoverThePhaseCube) {
  std::set<std::array<int, 3>> seen;
  for (int g = 0; g < mclari::kNumGroups; ++g) {
    const auto p = mclari::group_phases(g);
    std::array<int, 3> q;
    for (int i = 0; i < 3; ++i) {
      q[i] = int(std::lround(p[i] / (kPi / 2)));
      ASSERT_GE(q[i], 0);
      ASSERT_LE(q[i], 2);
      EXPECT_NEAR(p[i], q[i] * kPi / 2, 1e-12);
    }
    seen.insert(q);
  }
  EXPECT_EQ(seen.size(), 27u);  // distinct, and 27 of the 27 points of {0, pi/2, pi}^3
  EXPECT_EQ(mclari::group_name(0), "(0, 0, 0)");
  EXPECT_EQ(mclari::group_name(1), "(0, 0, pi/2)");  // seed figure 15 (II)
  EXPECT_EQ(mclari::group_name(24), "(pi, pi, 0)");  // seed figure 15 (XXV)
  EXPECT_THROW(mclari::group_phases(27), std::out_of_range);
  const auto& reduced = mclari::reduced_groups();
  EXPECT_EQ(reduced.size(), 8u);
  EXPECT_EQ(std::set<int>(reduced.begin(), reduced.end()).size(), 8u);
  for (int g : {0, 24, 20}) EXPECT_NE(std::find(reduced.begin(), reduced.end(), g), reduced.end());
}

TEST(McLari, PowerSpeedAndEfficiencyByHand) {
  // eta = m g v / P: 0.96 g, 9.81 m/s^2, 2 mm/s, 1e-4 W -> 0.96e-3 * 9.81 * 2e-3 / 1e-4.
  EXPECT_NEAR(McLariTask::efficiency(0.96, 9.81, 2.0, 1e-4), 0.188352, 1e-9);
  EXPECT_EQ(McLariTask::efficiency(0.96, 9.81, 2.0, 0.0), 0.0);
  // mean |tau omega| of (2 * 4, -3 * 5) = (8 + 15) / 2 g mm^2/s^3 = 11.5 nW.
  const double tau[2] = {2, -3}, omega[2] = {4, 5};
  EXPECT_NEAR(McLariTask::mean_abs_power_w(tau, omega, 2), 11.5e-9, 1e-18);

  // One real step: the figures the task reports agree with the centre-of-mass displacement and
  // with the formula; power sampled every 2 ms gives 500 samples per second at any f.
  for (int f : {1, 20}) {
    McLariTask task(fixed(f, 19));
    auto s = task.make_state();
    float obs[4], act[2] = {0, 0};
    task.reset_on(*s, 5, 0, obs);
    for (int k = 0; k < 2; ++k) task.step(*s, act, obs);
    const auto c0 = McLariTask::com(*s);
    const auto r = task.step(*s, act, obs);
    const auto c1 = McLariTask::com(*s);
    const auto& fig = st(*s).last;
    EXPECT_EQ(fig.power_samples, 500);
    EXPECT_EQ(fig.physics_steps, 500 * f);
    EXPECT_NEAR(fig.speed_mm_s, std::hypot(c1[0] - c0[0], c1[1] - c0[1]), 1e-9);
    double sum = 0;
    for (double p : fig.mean_abs_power) {
      EXPECT_GT(p, 0);
      sum += p;
    }
    EXPECT_NEAR(fig.power, sum, 1e-15);
    EXPECT_NEAR(fig.efficiency, 0.96e-3 * 9.81 * fig.speed_mm_s * 1e-3 / fig.power, 1e-9);
    EXPECT_NEAR(r.reward, fig.efficiency, 1e-6);
    EXPECT_NEAR(obs[0], fig.power / task.config().obs_power_scale(), 1e-4 * std::abs(obs[0]) + 1e-6);
    EXPECT_NEAR(obs[1], fig.speed_mm_s / task.config().obs_speed_scale(), 1e-5);
  }
}

TEST(McLari, HeightFieldShapeRangeAndFilter) {
  const int n = 40;
  const auto field = mclari::rough_height_field(n, 0.1, 3, 11);
  ASSERT_EQ(field.size(), size_t(n * n));
  for (float v : field) {
    ASSERT_GE(v, 0.f);
    ASSERT_LE(v, 1.f);
  }
  // The same steps by hand: N(0, 0.1) samples, min-max to [0, 1], then 3 x 3 means.
  auto raw = mclari::gaussian_field(n, 0.1, 11);
  double mean = 0, var = 0;
  for (float v : raw) mean += v / raw.size();
  for (float v : raw) var += (v - mean) * (v - mean) / raw.size();
  EXPECT_NEAR(std::sqrt(var), 0.1, 0.01);
  mclari::normalize_min_max(raw);
  EXPECT_FLOAT_EQ(*std::min_element(raw.begin(), raw.end()), 0.f);
  EXPECT_FLOAT_EQ(*std::max_element(raw.begin(), raw.end()), 1.f);
  auto at = [&](int i, int j) { return double(raw[size_t(i) * n + j]); };
  double interior = 0;
  for (int di = -1; di <= 1; ++di)
    for (int dj = -1; dj <= 1; ++dj) interior += at(7 + di, 9 + dj) / 9;
  EXPECT_NEAR(field[size_t(7) * n + 9], interior, 1e-6);
  const double corner = (at(0, 0) + at(0, 1) + at(1, 0) + at(1, 1)) / 4;
  EXPECT_NEAR(field[0], corner, 1e-6);
  // Smoothing: neighbouring differences shrink.
  double rough_diff = 0, smooth_diff = 0;
  for (int i = 0; i + 1 < n * n; ++i) {
    rough_diff += std::abs(raw[i + 1] - raw[i]);
    smooth_diff += std::abs(field[i + 1] - field[i]);
  }
  EXPECT_LT(smooth_diff, 0.5 * rough_diff);
  std::vector<float> v = {2, 4, 6};
  mclari::normalize_min_max(v);
  EXPECT_FLOAT_EQ(v[1], 0.5f);
  EXPECT_THROW(mclari::rough_height_field(n, 0.1, 2, 1), std::invalid_argument);
  EXPECT_THROW(mclari::rough_height_field(1, 0.1, 3, 1), std::invalid_argument);

  const auto png = (std::filesystem::temp_directory_path() / "mclari_test_hfield.png").string();
  mclari::write_height_png(png, field, n);
  std::ifstream in(png, std::ios::binary);
  char sig[8] = {};
  in.read(sig, 8);
  EXPECT_EQ(std::string(sig + 1, 3), "PNG");
  EXPECT_GT(std::filesystem::file_size(png), 100u);
  std::filesystem::remove(png);
  EXPECT_THROW(mclari::write_height_png("/nonexistent-dir/x.png", field, n), std::runtime_error);

  // The task's field is the thesis's 200 x 200 and the rough terrains use it.
  McLariTask task(farm::config::MclariConfig{});
  EXPECT_EQ(task.height_field().size(), 200u * 200u);
  EXPECT_EQ(task.terrain_model(3)->hfield_nrow[0], 200);
  EXPECT_EQ(task.terrain_model(0)->geom_contype[mj_name2id(task.terrain_model(0), mjOBJ_GEOM, "rough")], 0);
  EXPECT_NE(task.terrain_model(3)->geom_contype[mj_name2id(task.terrain_model(3), mjOBJ_GEOM, "rough")], 0);
  // Table I friction.
  const int plane = mj_name2id(task.model(), mjOBJ_GEOM, "plane");
  EXPECT_DOUBLE_EQ(task.terrain_model(1)->geom_friction[3 * plane], 0.1);
  EXPECT_DOUBLE_EQ(task.terrain_model(5)->geom_friction[3 * plane + 2], 1.0);
}

TEST(McLari, RewardAndTermination) {
  farm::config::MclariConfig c = fixed(1, 19);
  c.set_max_episode_steps(2);
  McLariTask task(c);
  auto s = task.make_state();
  float obs[4], act[2] = {0, 0};
  float metrics[7];

  // Plain step: reward = efficiency; the time limit truncates at 2 steps.
  task.reset_on(*s, 1, 0, obs);
  auto r = task.step(*s, act, obs);
  EXPECT_NEAR(r.reward, st(*s).last.efficiency, 1e-6);
  EXPECT_FALSE(r.terminated);
  EXPECT_FALSE(r.truncated);
  r = task.step(*s, act, obs);
  EXPECT_FALSE(r.terminated);
  EXPECT_TRUE(r.truncated);
  task.episode_metrics(*s, metrics);
  EXPECT_EQ(metrics[1], 0.f);
  EXPECT_EQ(metrics[2], 0.f);

  // Target at the robot: +10 on top of the efficiency, the episode ends, "reached".
  task.reset_on(*s, 1, 0, obs);
  const auto c0 = McLariTask::com(*s);
  st(*s).target[0] = c0[0];
  st(*s).target[1] = c0[1];
  r = task.step(*s, act, obs);
  EXPECT_TRUE(r.terminated);
  EXPECT_NEAR(r.reward, st(*s).last.efficiency + 10.0, 1e-5);
  task.episode_metrics(*s, metrics);
  EXPECT_EQ(metrics[2], 1.f);

  // Upside down: -100, the end, "fell".
  task.reset_on(*s, 1, 0, obs);
  mjData* d = s->data;
  d->qpos[2] = 6;
  d->qpos[3] = 0;
  d->qpos[4] = 1;  // 180 degrees about x
  d->qpos[5] = 0;
  d->qpos[6] = 0;
  mj_forward(st(*s).model, d);
  r = task.step(*s, act, obs);
  EXPECT_TRUE(r.terminated);
  EXPECT_FLOAT_EQ(r.reward, -100.f);
  task.episode_metrics(*s, metrics);
  EXPECT_EQ(metrics[1], 1.f);

  // Off the edge of the 1 m ground: -100, the end.
  task.reset_on(*s, 1, 0, obs);
  s->data->qpos[0] = 495;
  mj_forward(st(*s).model, s->data);
  r = task.step(*s, act, obs);
  EXPECT_TRUE(r.terminated);
  EXPECT_FLOAT_EQ(r.reward, -100.f);

  // Up in the air (left the ground): -100.
  task.reset_on(*s, 1, 0, obs);
  s->data->qpos[2] = 50;
  s->data->qvel[2] = 10000;  // mm/s upwards: still climbing after 1 s
  mj_forward(st(*s).model, s->data);
  r = task.step(*s, act, obs);
  EXPECT_TRUE(r.terminated);
  EXPECT_FLOAT_EQ(r.reward, -100.f);
}

TEST(McLari, ReferenceEfficiencyScalesTheRewardPerTerrain) {
  // The same fixed gait on plain-normal (0) and rough-wet (4): with references the efficiency term
  // is divided by the terrain's own value, the +10 stays, and the metrics keep raw efficiency.
  farm::config::MclariConfig c = fixed(150, 15);
  c.set_steps_per_period(20);
  c.set_max_timestep(0.002);
  const double ref[6] = {0.25, 1.5, 0.3, 0.125, 1.25, 0.1};
  for (double v : ref) c.add_reference_efficiency(v);
  McLariTask task(c);
  auto s = task.make_state();
  float obs[4], act[2] = {0, 0}, metrics[7];
  for (int terrain : {0, 4}) {
    task.reset_on(*s, 7, terrain, obs);
    auto r = task.step(*s, act, obs);
    const double eta = st(*s).last.efficiency;
    ASSERT_GT(eta, 0.0) << "terrain " << terrain;
    EXPECT_NEAR(r.reward, eta / ref[terrain], 1e-5 * eta / ref[terrain]) << "terrain " << terrain;
    task.episode_metrics(*s, metrics);
    EXPECT_NEAR(metrics[0], eta, 1e-6) << "terrain " << terrain;
  }
  task.reset_on(*s, 7, 3, obs);
  const auto c0 = McLariTask::com(*s);
  st(*s).target[0] = c0[0];
  st(*s).target[1] = c0[1];
  auto r = task.step(*s, act, obs);
  EXPECT_TRUE(r.terminated);
  EXPECT_NEAR(r.reward, st(*s).last.efficiency / ref[3] + 10.0, 1e-4);
}

TEST(McLari, ShareIsEfficiencyOverTheGoalAndZeroAfterAFall) {
  // "share" divides the episode's efficiency by its terrain's goal_efficiency (reference_efficiency
  // without it, 1 without either: metrics are finite) and is 0 for an episode that fell.
  farm::config::MclariConfig c = fixed(150, 15);
  c.set_steps_per_period(20);
  c.set_max_timestep(0.002);
  const double ref[6] = {0.25, 1.5, 0.3, 0.125, 1.25, 0.1}, goal[6] = {0.5, 3, 0.6, 0.25, 2.5, 0.2};
  float obs[4], act[2] = {0, 0}, m[7];
  {
    McLariTask task(c);
    auto s = task.make_state();
    task.reset_on(*s, 7, 4, obs);
    task.step(*s, act, obs);
    task.episode_metrics(*s, m);
    EXPECT_EQ(m[6], m[0]);
  }
  for (double v : ref) c.add_reference_efficiency(v);
  {
    McLariTask task(c);
    auto s = task.make_state();
    task.reset_on(*s, 7, 4, obs);
    task.step(*s, act, obs);
    task.episode_metrics(*s, m);
    ASSERT_GT(m[0], 0.f);
    EXPECT_NEAR(m[6], m[0] / ref[4], 1e-6);
  }
  for (double v : goal) c.add_goal_efficiency(v);
  McLariTask task(c);
  ASSERT_EQ(task.spec().metric_names.size(), 7u);
  EXPECT_EQ(task.spec().metric_names[6], "share");
  auto s = task.make_state();
  for (int terrain : {0, 4}) {
    task.reset_on(*s, 7, terrain, obs);
    task.step(*s, act, obs);
    task.episode_metrics(*s, m);
    ASSERT_GT(m[0], 0.f);
    EXPECT_NEAR(m[6], m[0] / goal[terrain], 1e-6) << "terrain " << terrain;
  }
  st(*s).fell = true;
  task.episode_metrics(*s, m);
  EXPECT_EQ(m[6], 0.f);
}

TEST(McLari, EvaluationConditionsAreTheTerrainsOnce) {
  // Evaluation episode k starts on the k-th distinct terrain of the config's list (a terrain listed
  // twice is drawn twice as often in training, but is one condition).
  farm::config::MclariConfig c;
  for (int t : {4, 1, 4, 3}) c.add_terrains(t);
  McLariTask task(c);
  ASSERT_EQ(task.eval_conditions(), 3);
  auto s = task.make_state();
  float obs[4];
  const int want[5] = {4, 1, 3, 4, 1};
  for (int k = 0; k < 5; ++k) {
    task.reset_in_condition(*s, 11, k, obs);
    EXPECT_EQ(st(*s).terrain, want[k]) << "condition " << k;
  }
  McLariTask all(farm::config::MclariConfig{});
  EXPECT_EQ(all.eval_conditions(), 6);
}

TEST(McLari, TendonsPushOnlyBelowTheirRestLength) {
  McLariTask task(farm::config::MclariConfig{});
  auto s = task.make_state();
  float obs[4];
  task.reset_on(*s, 1, 0, obs);
  const mjModel* m = st(*s).model;
  mjData* d = s->data;
  const int j0 = m->jnt_qposadr[mj_name2id(m, mjOBJ_JOINT, "stretch0")];
  const int j2 = m->jnt_qposadr[mj_name2id(m, mjOBJ_JOINT, "stretch2")];
  const int v0 = m->jnt_dofadr[mj_name2id(m, mjOBJ_JOINT, "stretch0")];
  // Facing hips 10 mm apart at rest: no force.
  mj_forward(m, d);
  EXPECT_NEAR(d->ten_length[0], 10.0, 1e-3);
  task.apply_tendon_springs(m, d);
  for (int i = 0; i < m->nv; ++i) EXPECT_EQ(d->qfrc_applied[i], 0.0);
  // Both hips 1.5 mm in: 7 mm, 1 mm short of 8, pushed out with 1000 g/s^2 * 1 mm along each slide.
  d->qpos[j0] = -1.5;
  d->qpos[j2] = -1.5;
  mj_forward(m, d);
  EXPECT_NEAR(d->ten_length[0], 7.0, 1e-3);
  task.apply_tendon_springs(m, d);
  EXPECT_NEAR(d->qfrc_applied[v0], 1000.0, 1.0);
}

TEST(McLari, BadConfigIsNamed) {
  auto expect_error = [](const farm::config::MclariConfig& c, const std::string& field) {
    try {
      McLariTask t(c);
      ADD_FAILURE() << "no error for " << field;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(field), std::string::npos) << e.what();
    }
  };
  farm::config::MclariConfig c;
  c.set_voltage(-1);
  expect_error(c, "voltage");
  c = {};
  c.add_terrains(6);
  expect_error(c, "terrains");
  c = {};
  c.set_fixed_group(27);
  expect_error(c, "fixed_group");
  c = {};
  c.set_steps_per_period(0);
  expect_error(c, "steps_per_period");
  c = {};
  c.add_goal_efficiency(0.2);
  expect_error(c, "goal_efficiency");  // one per terrain
  c = {};
  for (int t = 0; t < 6; ++t) c.add_goal_efficiency(t == 3 ? 0 : 0.2);
  expect_error(c, "goal_efficiency");  // > 0
  c = {};
  c.set_reduced_groups(true);
  c.set_initial_group(8);
  expect_error(c, "initial_group");
  c = {};
  c.add_groups(27);
  expect_error(c, "groups");  // not a group
  c = {};
  c.add_groups(11);
  c.add_groups(11);
  expect_error(c, "twice");
  c = {};
  c.add_groups(11);
  c.set_reduced_groups(true);
  expect_error(c, "not both");
  c = {};
  for (int t = 0; t < 5; ++t) c.add_reference_efficiency(1.0);
  expect_error(c, "reference_efficiency");  // one per terrain
  c.add_reference_efficiency(0.0);
  expect_error(c, "reference_efficiency");  // six, but one is not > 0
  c = {};
  c.add_frequencies(151);
  expect_error(c, "frequencies");  // above max_frequency
  c = {};
  c.add_frequencies(1);
  c.add_frequencies(1);
  expect_error(c, "1 Hz twice");
}
