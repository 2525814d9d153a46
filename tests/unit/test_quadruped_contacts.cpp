// Quadrupeds of seed 000 (Unitree A1, Honey Badger, Silver Badger): contact queries of the legged
// layer and what counts as a fall, on the real MuJoCo models.
#include <gtest/gtest.h>
#include <mujoco/mujoco.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <vector>

#include "quadruped/legged.h"
#include "quadruped/quadruped_task.h"
#include "quadruped_testing.h"
#include "task.h"

using namespace farm;
using namespace farm::robots;
using namespace farm::robots::quadruped;
using namespace farm::robots::quadruped::test_support;

namespace {

double total_mass(const mjModel* m) {
  double s = 0;
  for (int b = 0; b < m->nbody; ++b) s += m->body_mass[b];
  return s;
}

}  // namespace

TEST(Quadruped, ContactQueriesReportTheRightPairs) {
  for (const char* name : kRobots) {
    SCOPED_TRACE(name);
    auto task = quiet_task(name);
    auto s = task->make_state();
    auto& qs = static_cast<QuadrupedState&>(*s);
    std::vector<float> obs(task->spec().obs_dim), zero(task->spec().act_dim, 0.f);
    task->reset(*s, 21, obs.data());
    for (int k = 0; k < 100; ++k) task->step(*s, zero.data(), obs.data());  // settle: 2 s
    const mjModel* m = qs.model;
    mjData* d = qs.data;
    mj_forward(m, d);
    EXPECT_TRUE(legged::touching(m, d, task->feet(), task->floor()));
    EXPECT_EQ(legged::count_touching(m, d, task->feet(), task->floor()), 4);
    EXPECT_FALSE(legged::touching(m, d, task->trunk(), task->floor()));
    EXPECT_EQ(legged::count_touching(m, d, task->legs(), task->floor()), 0);
    // Standing still, the floor carries the robot's weight through the feet: the feet's net
    // vertical contact force is m g, each foot's positive.
    std::vector<double> f;
    legged::net_contact_forces(m, d, task->feet(), f);
    double fz = 0;
    for (int i = 0; i < 4; ++i) {
      EXPECT_GT(f[3 * i + 2], 0.0) << "foot " << i;
      fz += f[3 * i + 2];
    }
    EXPECT_NEAR(fz, total_mass(m) * 9.81, 0.05 * total_mass(m) * 9.81);
    // The floor feels the opposite.
    legged::net_contact_forces(m, d, task->floor(), f);
    EXPECT_NEAR(f[2], -fz, 1e-6 * fz);
    // Lay the trunk on the floor: trunk-floor contact, and the step ends the episode as a fall.
    const double z = 0.03;
    legged::write_property(m, d, legged::Property::kBodyHeight, task->trunk_body(), &z);
    mj_forward(m, d);
    EXPECT_TRUE(legged::touching(m, d, task->trunk(), task->floor()));
    const StepResult r = task->step(*s, zero.data(), obs.data());
    EXPECT_TRUE(r.terminated);
    std::vector<float> metrics(task->spec().metric_names.size());
    task->episode_metrics(*s, metrics.data());
    EXPECT_EQ(metrics[3], 1.f);  // fell
  }
}

TEST(Quadruped, RestingOnTheHipHousingsIsAFall) {
  // Pitched 55 degrees nose-down, the front hip housings are the lowest part of the trunk and
  // carry it with its centre well above min_base_height: a fall all the same. (The A1's hips
  // stick out furthest; on the Badgers the trunk box reaches the floor in this pose too.)
  for (const char* name : kRobots) {
    auto task = quiet_task(name);
    for (const char* hip : {"FL_hip_geom", "FR_hip_geom", "RL_hip_geom", "RR_hip_geom"}) {
      const int g = mj_name2id(task->model(), mjOBJ_GEOM, hip);
      EXPECT_NE(std::find(task->trunk().geoms.begin(), task->trunk().geoms.end(), g), task->trunk().geoms.end())
          << name << ": " << hip << " is not in the fall group";
    }
  }
  {
    auto task = quiet_task("a1");
    auto s = task->make_state();
    auto& qs = static_cast<QuadrupedState&>(*s);
    std::vector<float> obs(task->spec().obs_dim);
    task->reset(*s, 3, obs.data());
    const mjModel* m = qs.model;
    mjData* d = qs.data;
    const double pitch = 55.0 * M_PI / 180.0;
    d->qpos[3] = std::cos(pitch / 2);
    d->qpos[4] = 0;
    d->qpos[5] = std::sin(pitch / 2);  // about +y: the nose goes down
    d->qpos[6] = 0;
    d->qpos[2] = 1.0;
    mj_kinematics(m, d);
    const int hip = mj_name2id(m, mjOBJ_GEOM, "FL_hip_geom");
    ASSERT_GE(hip, 0);
    const double hip_bottom = d->geom_xpos[3 * hip + 2] - m->geom_size[3 * hip];
    const int trunk_geom = mj_name2id(m, mjOBJ_GEOM, "trunk_geom");
    // Lower the robot until the hip sinks 2 mm into the floor.
    d->qpos[2] -= hip_bottom + 0.002;
    mj_forward(m, d);
    double z;
    legged::read_property(m, d, legged::Property::kBodyHeight, task->trunk_body(), &z);
    EXPECT_GT(z, task->config().min_base_height()) << "the height alone would not end it";
    bool hip_contact = false, trunk_box_contact = false;
    for (int i = 0; i < d->ncon; ++i) {
      const auto& c = d->contact[i];
      hip_contact |= c.geom1 == hip || c.geom2 == hip;
      trunk_box_contact |= c.geom1 == trunk_geom || c.geom2 == trunk_geom;
    }
    EXPECT_TRUE(hip_contact);
    EXPECT_FALSE(trunk_box_contact) << "the trunk box alone would not end it";
    EXPECT_TRUE(task->fallen(qs));
    // 5 cm higher, in the air: no fall.
    d->qpos[2] += 0.05;
    mj_forward(m, d);
    bool any_trunk_group = legged::touching(m, d, task->trunk(), task->floor());
    EXPECT_FALSE(any_trunk_group);
    EXPECT_FALSE(task->fallen(qs));
  }
}
