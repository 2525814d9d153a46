// Mobile robots of the mobile-robots paper (Jetbot, Kaya): kinematics, lidar, obstacle maps, reward, action
// spaces, on the real MuJoCo models.
#include <gtest/gtest.h>
#include <mujoco/mujoco.h>

#include <cmath>
#include <memory>
#include <random>
#include <stdexcept>
#include <vector>

#include "mobile/kinematics.h"
#include "mobile/mobile_task.h"
#include "task.h"

using namespace farm;
using namespace farm::robots;
using namespace farm::robots::mobile;

namespace {

config::TaskConfig task_config(const std::string& name, bool discrete = true) {
  config::TaskConfig c;
  c.set_name(name);
  auto* scene = name == "jetbot" ? c.mutable_jetbot()->mutable_scene() : c.mutable_kaya()->mutable_scene();
  scene->set_discrete_actions(discrete);
  return c;
}

std::unique_ptr<MobileTask> make(const config::TaskConfig& c) {
  auto t = make_task(c);
  return std::unique_ptr<MobileTask>(static_cast<MobileTask*>(t.release()));
}

MobileMap empty_map(double sx, double sy, double syaw, double gx, double gy) {
  MobileMap m;
  m.start_x = sx;
  m.start_y = sy;
  m.start_yaw = syaw;
  m.goal_x = gx;
  m.goal_y = gy;
  return m;
}

}  // namespace

TEST(MobileKinematics, DifferentialMatchesHandComputedCases) {
  // r = 0.03, R = 0.1125. Straight: both wheels V / r.
  auto s = differential_wheel_speeds(0.3, 0.0, 0.03, 0.1125);
  EXPECT_NEAR(s.left, 10.0, 1e-12);
  EXPECT_NEAR(s.right, 10.0, 1e-12);
  // Turning on the spot at 1 rad/s: +-W R / (2 r) = +-1.875.
  s = differential_wheel_speeds(0.0, 1.0, 0.03, 0.1125);
  EXPECT_NEAR(s.left, -1.875, 1e-12);
  EXPECT_NEAR(s.right, 1.875, 1e-12);
  // V = 0.2, W = 2: (0.4 -+ 0.225) / 0.06.
  s = differential_wheel_speeds(0.2, 2.0, 0.03, 0.1125);
  EXPECT_NEAR(s.left, 0.175 / 0.06, 1e-12);
  EXPECT_NEAR(s.right, 0.625 / 0.06, 1e-12);
}

TEST(MobileKinematics, HolonomicMatchesHandComputedCases) {
  // r = 0.04, L = 0.125.
  auto s = holonomic_wheel_speeds(1.0, 0.0, 0.0, 0.04, 0.125);
  EXPECT_NEAR(s.a, -25.0, 1e-12);
  EXPECT_NEAR(s.b, 12.5, 1e-12);
  EXPECT_NEAR(s.c, 12.5, 1e-12);
  s = holonomic_wheel_speeds(0.0, 1.0, 0.0, 0.04, 0.125);
  EXPECT_NEAR(s.a, 0.0, 1e-12);
  EXPECT_NEAR(s.b, -std::sqrt(3.0) / 2 / 0.04, 1e-12);
  EXPECT_NEAR(s.c, std::sqrt(3.0) / 2 / 0.04, 1e-12);
  s = holonomic_wheel_speeds(0.0, 0.0, 1.0, 0.04, 0.125);
  EXPECT_NEAR(s.a, 3.125, 1e-12);
  EXPECT_NEAR(s.b, 3.125, 1e-12);
  EXPECT_NEAR(s.c, 3.125, 1e-12);
  // Every wheel's rim speed is the base velocity at the wheel along its drive direction.
  const double vx = 0.2, vy = -0.1, w = 0.7, r = 0.04, L = 0.125;
  s = holonomic_wheel_speeds(vx, vy, w, r, L);
  const double angles[3] = {M_PI / 2, 7 * M_PI / 6, 11 * M_PI / 6};
  const double speeds[3] = {s.a, s.b, s.c};
  for (int i = 0; i < 3; ++i) {
    const double dx = -std::sin(angles[i]), dy = std::cos(angles[i]);
    EXPECT_NEAR(speeds[i] * r, dx * vx + dy * vy + w * L, 1e-12) << "wheel " << i;
  }
}

TEST(MobileKinematics, ModelsUseTheGeometryOfTheirMjcf) {
  auto jet = make(task_config("jetbot"));
  EXPECT_NEAR(jet->wheel_radius(), 0.03, 1e-9);
  EXPECT_NEAR(jet->wheel_offset(), 0.1125, 1e-9);
  auto kaya = make(task_config("kaya"));
  EXPECT_NEAR(kaya->wheel_radius(), 0.04, 1e-9);
  EXPECT_NEAR(kaya->wheel_offset(), 0.125, 1e-6);
}

// Drives with a fixed base command on an empty map and returns the mean base velocity (base
// frame) over the second half of `steps` agent steps.
std::array<double, 3> drive(MobileTask& t, const float* action, int steps) {
  auto s = t.make_state();
  std::vector<float> obs(t.spec().obs_dim);
  t.reset_to(*s, empty_map(0, 0, 0.3, 1.9, 1.9), obs.data());
  std::array<double, 3> sum{0, 0, 0};
  int n = 0;
  for (int i = 0; i < steps; ++i) {
    t.step(*s, action, obs.data());
    if (i >= steps / 2) {
      double vx, vy, w;
      t.base_velocity(*s, &vx, &vy, &w);
      sum[0] += vx;
      sum[1] += vy;
      sum[2] += w;
      ++n;
    }
  }
  for (auto& v : sum) v /= n;
  return sum;
}

TEST(MobileSimulation, JetbotTracksItsBaseCommand) {
  auto t = make(task_config("jetbot", /*discrete=*/false));
  const float fwd[2] = {0.5f, 0.0f};  // 0.15 m/s straight
  auto v = drive(*t, fwd, 10);
  EXPECT_NEAR(v[0], 0.15, 0.015);
  EXPECT_NEAR(v[1], 0.0, 0.01);
  EXPECT_NEAR(v[2], 0.0, 0.05);
  const float turn[2] = {0.0f, 0.5f};  // 1 rad/s on the spot
  v = drive(*t, turn, 10);
  EXPECT_NEAR(v[0], 0.0, 0.02);
  EXPECT_NEAR(v[2], 1.0, 0.1);
}

TEST(MobileSimulation, KayaMovesHolonomically) {
  auto t = make(task_config("kaya", /*discrete=*/false));
  // Sideways, diagonal and turning: the base follows (Vx, Vy, W) in its own frame.
  const float cases[][3] = {{0.f, 0.5f, 0.f}, {0.5f, 0.f, 0.f}, {-0.5f, 0.5f, 0.f}, {0.f, 0.f, 0.5f}};
  for (const auto& a : cases) {
    auto v = drive(*t, a, 10);
    EXPECT_NEAR(v[0], 0.3 * a[0], 0.02) << a[0] << " " << a[1] << " " << a[2];
    EXPECT_NEAR(v[1], 0.3 * a[1], 0.02) << a[0] << " " << a[1] << " " << a[2];
    EXPECT_NEAR(v[2], 2.0 * a[2], 0.1) << a[0] << " " << a[1] << " " << a[2];
  }
}

TEST(MobileLidar, DistancesMatchKnownGeometry) {
  config::TaskConfig c = task_config("jetbot");
  auto* scene = c.mutable_jetbot()->mutable_scene();
  scene->set_lidar_rays(12);
  scene->set_lidar_range(3.0);
  scene->set_arena_half_size(2.0);
  scene->set_min_obstacles(0);
  scene->set_max_obstacles(2);
  scene->set_obstacle_min_half_size(0.1);  // slot 0: box, half extent 0.1
  scene->set_obstacle_max_half_size(0.2);  // slot 1: cylinder, radius 0.2
  auto t = make(c);
  ASSERT_TRUE(t->maps().slots()[0].box);
  ASSERT_FALSE(t->maps().slots()[1].box);
  MobileMap m = empty_map(0, 0, 0, 1.5, 1.5);
  m.obstacles.push_back({1, 0.6, 0.0, 0.0});   // cylinder ahead, surface at 0.4
  m.obstacles.push_back({0, 0.0, -0.5, 0.0});  // box to the right, face at 0.4
  auto s = t->make_state();
  std::vector<float> obs(t->spec().obs_dim);
  t->reset_to(*s, m, obs.data());
  std::vector<double> d(12);
  t->lidar().scan(t->model(), s->data, d.data());
  EXPECT_NEAR(d[0], 0.4, 1e-6);  // ahead: the cylinder
  EXPECT_NEAR(d[3], 2.0, 1e-6);  // left (+y): the north wall
  EXPECT_NEAR(d[6], 2.0, 1e-6);  // behind: the west wall
  EXPECT_NEAR(d[9], 0.4, 1e-6);  // right (-y): the box
  // 30 degrees: the cylinder is missed (its edge is at atan(0.2 / 0.6) = 18 degrees); the wall
  // x = 2 lies at 2 / cos 30.
  EXPECT_NEAR(d[1], 2.0 / std::cos(M_PI / 6), 1e-6);
  EXPECT_NEAR(obs[0], 0.4 / 3.0, 1e-6);  // normalized by the range in the observation
  // Turn the robot by 90 degrees: the cylinder is now on its right.
  m.start_yaw = M_PI / 2;
  t->reset_to(*s, m, obs.data());
  t->lidar().scan(t->model(), s->data, d.data());
  EXPECT_NEAR(d[9], 0.4, 1e-6);
  EXPECT_NEAR(d[0], 2.0, 1e-6);
  // A range shorter than the walls clips to the range.
  scene->set_lidar_range(1.0);
  auto t1 = make(c);
  auto s1 = t1->make_state();
  std::vector<float> obs1(t1->spec().obs_dim);
  t1->reset_to(*s1, empty_map(0, 0, 0, 1.5, 1.5), obs1.data());
  t1->lidar().scan(t1->model(), s1->data, d.data());
  for (int i = 0; i < 12; ++i) EXPECT_DOUBLE_EQ(d[i], 1.0) << "ray " << i;
}

TEST(MobileMaps, StartAndGoalNeverOverlapObstacles) {
  for (const char* name : {"jetbot", "kaya"}) {
    config::TaskConfig c = task_config(name);
    auto* scene =
        std::string(name) == "jetbot" ? c.mutable_jetbot()->mutable_scene() : c.mutable_kaya()->mutable_scene();
    scene->set_min_obstacles(8);
    scene->set_max_obstacles(12);
    auto t = make(c);
    const double keep = t->robot_radius() + scene->clearance();
    const double h = scene->arena_half_size();
    std::mt19937_64 rng(7);
    int total_obstacles = 0;
    for (int i = 0; i < 1000; ++i) {
      MobileMap m = t->maps().draw(rng);
      total_obstacles += int(m.obstacles.size());
      ASSERT_GE(int(m.obstacles.size()), 8);
      ASSERT_LE(int(m.obstacles.size()), 12);
      for (const auto& o : m.obstacles) {
        const auto& slot = t->maps().slots()[o.slot];
        ASSERT_GE(distance_to_obstacle(slot, o, m.start_x, m.start_y), keep) << name << " map " << i;
        ASSERT_GE(distance_to_obstacle(slot, o, m.goal_x, m.goal_y), keep) << name << " map " << i;
        ASSERT_LE(std::abs(o.x) + slot.bound(), h + 1e-9);
      }
      ASSERT_LE(std::abs(m.start_x), h - keep);
      ASSERT_LE(std::abs(m.goal_y), h - keep);
      ASSERT_GE(std::hypot(m.goal_x - m.start_x, m.goal_y - m.start_y), scene->min_start_goal_distance());
    }
    EXPECT_GT(total_obstacles, 8 * 1000);
  }
}

TEST(MobileMaps, StartsWithoutContactAndStaticMapKeepsObstacles) {
  config::TaskConfig c = task_config("jetbot");
  c.mutable_jetbot()->mutable_scene()->set_static_map(true);
  auto t = make(c);
  auto s = t->make_state();
  std::vector<float> obs(t->spec().obs_dim);
  t->reset(*s, 1, obs.data());
  const auto first = static_cast<MobileState&>(*s).map;
  for (uint64_t seed = 2; seed < 50; ++seed) {
    t->reset(*s, seed, obs.data());
    const auto& m = static_cast<MobileState&>(*s).map;
    ASSERT_EQ(m.obstacles.size(), first.obstacles.size());
    for (size_t i = 0; i < m.obstacles.size(); ++i) EXPECT_EQ(m.obstacles[i].x, first.obstacles[i].x);
    // The robot starts clear of every obstacle: no contact with the world.
    for (int k = 0; k < s->data->ncon; ++k) {
      EXPECT_LT(t->model()->geom_group[s->data->contact[k].geom1] + t->model()->geom_group[s->data->contact[k].geom2],
                3)
          << "seed " << seed;
    }
  }
  // Without static_map the obstacles change between resets.
  auto t2 = make(task_config("jetbot"));
  auto s2 = t2->make_state();
  t2->reset(*s2, 1, obs.data());
  const auto a = static_cast<MobileState&>(*s2).map;
  t2->reset(*s2, 2, obs.data());
  const auto b = static_cast<MobileState&>(*s2).map;
  EXPECT_TRUE(a.obstacles.size() != b.obstacles.size() || a.obstacles[0].x != b.obstacles[0].x);
}

TEST(MobileReward, FollowsEquationNine) {
  config::TaskConfig c = task_config("jetbot");
  auto* scene = c.mutable_jetbot()->mutable_scene();
  scene->set_max_episode_steps(100);
  scene->set_distance_weight(0.5);
  scene->set_collision_penalty(7.0);
  scene->set_landing_reward(30.0);
  scene->set_goal_radius(0.1);
  scene->set_min_obstacles(0);
  scene->set_max_obstacles(2);
  auto t = make(c);
  auto s = t->make_state();
  auto& ms = static_cast<MobileState&>(*s);
  std::vector<float> obs(t->spec().obs_dim);
  const float stay[1] = {3.f};  // turn left on the spot: the position barely changes
  // Driving: -w d (1 - i / N).
  t->reset_to(*s, empty_map(0, 0, 0, 1.0, 0), obs.data());
  for (int i = 1; i <= 3; ++i) {
    StepResult r = t->step(*s, stay, obs.data());
    double x, y, yaw;
    t->pose(*s, &x, &y, &yaw);
    EXPECT_NEAR(r.reward, -0.5 * std::hypot(1.0 - x, y) * (1 - i / 100.0), 1e-5);
    EXPECT_FALSE(r.terminated);
  }
  // Reaching the goal: r_l (1 - i / N), and the episode ends.
  t->reset_to(*s, empty_map(0, 0, 0, 0.05, 0), obs.data());
  StepResult r = t->step(*s, stay, obs.data());
  EXPECT_TRUE(r.terminated);
  EXPECT_TRUE(ms.reached);
  EXPECT_NEAR(r.reward, 30.0 * (1 - 1 / 100.0), 1e-5);
  // Collision: -p, and the episode ends. A box right ahead, driven into.
  MobileMap m = empty_map(0, 0, 0, -1.5, 0);
  m.obstacles.push_back({0, 0.25, 0.0, 0.0});
  t->reset_to(*s, m, obs.data());
  const float forward[1] = {0.f};
  bool ended = false;
  for (int i = 0; i < 20 && !ended; ++i) {
    r = t->step(*s, forward, obs.data());
    ended = r.terminated;
  }
  EXPECT_TRUE(ended);
  EXPECT_TRUE(ms.collided);
  EXPECT_FLOAT_EQ(r.reward, -7.0f);
  std::vector<float> metrics(t->spec().metric_names.size());
  t->episode_metrics(*s, metrics.data());
  EXPECT_EQ(metrics[0], 0.f);  // success
  EXPECT_EQ(metrics[3], 1.f);  // collision
  EXPECT_GT(metrics[2], 0.f);  // path length
  // Time limit: truncated, not terminated.
  t->reset_to(*s, empty_map(0, 0, 0, 1.5, 1.5), obs.data());
  for (int i = 0; i < 100; ++i) r = t->step(*s, stay, obs.data());
  EXPECT_TRUE(r.truncated);
  EXPECT_FALSE(r.terminated);
}

TEST(MobileActions, OneFieldSwitchesDiscreteAndContinuous) {
  auto jd = make(task_config("jetbot", true));
  EXPECT_EQ(jd->spec().act_dim, 1);
  EXPECT_EQ(jd->spec().num_actions, 7);
  auto jc = make(task_config("jetbot", false));
  EXPECT_EQ(jc->spec().act_dim, 2);
  EXPECT_EQ(jc->spec().num_actions, 0);
  auto kd = make(task_config("kaya", true));
  EXPECT_EQ(kd->spec().act_dim, 1);
  EXPECT_EQ(kd->spec().num_actions, 10);
  auto kc = make(task_config("kaya", false));
  EXPECT_EQ(kc->spec().act_dim, 3);
  EXPECT_EQ(kc->spec().obs_dim, 12 + 3 + 3 + 3);
  EXPECT_EQ(jc->spec().obs_dim, 12 + 3 + 2 + 3);
  // Discrete index k is the k-th base command; the box scales to the top speeds.
  const float a4[1] = {4.f};  // the tight arc to the right: half speed, half the top turn rate
  auto cmd = jd->base_command(a4);
  EXPECT_DOUBLE_EQ(cmd[0], 0.15);
  EXPECT_DOUBLE_EQ(cmd[2], -1.0);
  const float box[2] = {1.f, -0.25f};
  cmd = jc->base_command(box);
  EXPECT_DOUBLE_EQ(cmd[0], 0.3);
  EXPECT_DOUBLE_EQ(cmd[2], -0.5);
  const float kbox[3] = {0.5f, -1.f, 2.f};  // clipped to [-1, 1]
  cmd = kc->base_command(kbox);
  EXPECT_DOUBLE_EQ(cmd[1], -0.3);
  EXPECT_DOUBLE_EQ(cmd[2], 2.0);
  // A bad index is an error that names it.
  const float bad[1] = {7.f};
  try {
    jd->base_command(bad);
    FAIL() << "expected an error";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("[0, 7)"), std::string::npos) << e.what();
  }
  const float half[1] = {1.5f};
  EXPECT_THROW(jd->base_command(half), std::invalid_argument);
}

TEST(MobileConfig, BadFieldsAreNamed) {
  config::TaskConfig c = task_config("jetbot");
  c.mutable_jetbot()->mutable_scene()->set_max_obstacles(2);
  c.mutable_jetbot()->mutable_scene()->set_min_obstacles(3);
  try {
    make_task(c);
    FAIL() << "expected an error";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("max_obstacles"), std::string::npos) << e.what();
  }
  c = task_config("kaya");
  c.mutable_kaya()->mutable_scene()->set_lidar_rays(0);
  EXPECT_THROW(make_task(c), std::invalid_argument);
  // A map that cannot hold start and goal is reported, not looped on forever.
  c = task_config("jetbot");
  auto* scene = c.mutable_jetbot()->mutable_scene();
  scene->set_arena_half_size(0.5);
  scene->set_min_obstacles(8);
  scene->set_max_obstacles(8);
  scene->set_obstacle_min_half_size(0.3);
  scene->set_obstacle_max_half_size(0.4);
  scene->set_max_reset_tries(20);
  auto t = make(c);
  auto s = t->make_state();
  std::vector<float> obs(t->spec().obs_dim);
  EXPECT_THROW(t->reset(*s, 1, obs.data()), std::runtime_error);
}

// The bases stay on their wheels: random discrete commands (the DQN's exploration) for 30 s on
// an empty arena never lift or tilt the base, at the default timestep and the training config's.
TEST(MobileSimulation, BasesStayUprightUnderRandomCommands) {
  for (const char* name : {"jetbot", "kaya"}) {
    for (double dt : {0.005, 0.01}) {
      auto c = task_config(name);
      auto* scene =
          std::string(name) == "jetbot" ? c.mutable_jetbot()->mutable_scene() : c.mutable_kaya()->mutable_scene();
      scene->set_physics_dt(dt);
      scene->set_control_substeps(int(std::lround(0.1 / dt)));
      auto t = make(c);
      auto s = t->make_state();
      std::vector<float> obs(t->spec().obs_dim);
      t->reset_to(*s, empty_map(0, 0, 0, 1.9, 1.9), obs.data());
      const mjModel* m = t->model();
      const int base = mj_name2id(m, mjOBJ_BODY, "base");
      const double z0 = s->data->xpos[3 * base + 2];
      std::mt19937_64 rng(3);
      std::uniform_int_distribution<int> pick(0, t->spec().num_actions - 1);
      double max_dz = 0, min_up = 1;
      for (int i = 0; i < 300; ++i) {
        const float a = float(pick(rng));
        t->step(*s, &a, obs.data());
        double x, y, yaw;
        t->pose(*s, &x, &y, &yaw);
        if (std::abs(x) > 1.5 || std::abs(y) > 1.5) t->reset_to(*s, empty_map(0, 0, yaw, 1.9, 1.9), obs.data());
        max_dz = std::max(max_dz, std::abs(s->data->xpos[3 * base + 2] - z0));
        min_up = std::min(min_up, double(s->data->xmat[9 * base + 8]));  // base z axis, world z
      }
      EXPECT_LT(max_dz, 0.01) << name << " dt " << dt;
      EXPECT_GT(min_up, std::cos(10 * M_PI / 180)) << name << " dt " << dt;
    }
  }
}
