// mCLARI microbot (mCLARI thesis): how the action picks the gait (frequency and phase group, from the
// seed's step rule or from explicit sets) and the observation of the gait and the terrain.
#include <gtest/gtest.h>

#include <cmath>
#include <utility>
#include <vector>

#include "mclari/mclari_task.h"
#include "mclari/phase_groups.h"
#include "task.h"

using farm::robots::McLariState;
using farm::robots::McLariTask;
namespace mclari = farm::robots::mclari;

namespace {

McLariState& st(farm::robots::TaskState& s) { return static_cast<McLariState&>(s); }

}  // namespace

TEST(McLari, ActionScaling) {
  EXPECT_EQ(McLariTask::next_frequency(1, 1.f, 5, 1, 150), 6);
  EXPECT_EQ(McLariTask::next_frequency(148, 1.f, 5, 1, 150), 150);
  EXPECT_EQ(McLariTask::next_frequency(3, -1.f, 5, 1, 150), 1);
  EXPECT_EQ(McLariTask::next_frequency(10, 0.5f, 5, 1, 150), 13);  // 12.5 rounds to 13
  EXPECT_EQ(McLariTask::next_frequency(10, NAN, 5, 1, 150), 10);
  EXPECT_EQ(McLariTask::group_index_from_action(-1.f, 27), 0);
  EXPECT_EQ(McLariTask::group_index_from_action(1.f, 27), 26);
  EXPECT_EQ(McLariTask::group_index_from_action(0.f, 8), 4);
  EXPECT_EQ(McLariTask::group_index_from_action(-0.76f, 8), 0);

  farm::config::MclariConfig c;
  c.set_reduced_groups(true);
  McLariTask task(c);
  auto s = task.make_state();
  float obs[4], act[2] = {1.f, 1.f};
  task.reset_on(*s, 1, 0, obs);
  task.step(*s, act, obs);
  EXPECT_EQ(st(*s).frequency, 6);
  EXPECT_EQ(st(*s).last.group, mclari::reduced_groups().back());

  // An explicit set: a1 is cut into as many parts as it lists, in its order.
  farm::config::MclariConfig e;
  for (int g : {15, 5, 20}) e.add_groups(g);
  McLariTask chosen(e);
  ASSERT_EQ(chosen.active_groups(), (std::vector<int>{15, 5, 20}));
  auto t = chosen.make_state();
  chosen.reset_on(*t, 1, 0, obs);
  for (const auto& [a1, group] : {std::pair{-1.f, 15}, {0.f, 5}, {-0.3f, 5}, {0.34f, 20}, {1.f, 20}}) {
    act[1] = a1;
    chosen.step(*t, act, obs);
    EXPECT_EQ(st(*t).last.group, group) << "a1 = " << a1;
  }

  // An explicit frequency set: a0 picks one outright, wherever f was.
  farm::config::MclariConfig fs;
  fs.set_max_timestep(0.002);
  fs.set_steps_per_period(20);
  for (int f : {1, 150, 60}) fs.add_frequencies(f);
  McLariTask picked(fs);
  auto u = picked.make_state();
  picked.reset_on(*u, 1, 0, obs);
  for (const auto& [a0, f] : {std::pair{1.f, 60}, {-1.f, 1}, {0.f, 150}, {-0.3f, 150}, {-0.34f, 1}, {0.34f, 60}}) {
    act[0] = a0;
    picked.step(*u, act, obs);
    EXPECT_EQ(st(*u).frequency, f) << "a0 = " << a0;
    EXPECT_EQ(st(*u).last.frequency, f) << "a0 = " << a0;
  }
}

TEST(McLari, ObservedGait) {
  farm::config::MclariConfig c;
  c.set_steps_per_period(20);
  c.set_max_timestep(0.002);
  c.set_frequency_step(149);
  c.set_initial_frequency(1);
  c.set_initial_group(3);
  EXPECT_EQ(McLariTask(c).spec().obs_dim, 4);
  c.set_observe_gait(true);
  McLariTask task(c);
  ASSERT_EQ(task.spec().obs_dim, 6);
  auto s = task.make_state();
  float obs[6], act[2] = {1.f, 1.f};
  task.reset_on(*s, 1, 0, obs);
  EXPECT_FLOAT_EQ(obs[4], 1.f / 150.f);  // the initial gait: 1 Hz, group index 3 of 27
  EXPECT_FLOAT_EQ(obs[5], 3.f / 26.f);
  task.step(*s, act, obs);  // f = 1 + 149 = 150, the last group
  EXPECT_FLOAT_EQ(obs[4], 1.f);
  EXPECT_FLOAT_EQ(obs[5], 1.f);
  act[0] = -0.5f;  // 150 - 74.5 rounds to 76 (75.5 away from zero)
  act[1] = -1.f;
  task.step(*s, act, obs);
  EXPECT_FLOAT_EQ(obs[4], 76.f / 150.f);
  EXPECT_FLOAT_EQ(obs[5], 0.f);
}

TEST(McLari, ObservedTerrain) {
  farm::config::MclariConfig c;
  c.set_steps_per_period(20);
  c.set_max_timestep(0.002);
  c.set_observe_terrain(true);
  EXPECT_EQ(McLariTask(c).spec().obs_dim, 7);
  c.set_observe_gait(true);
  McLariTask task(c);
  ASSERT_EQ(task.spec().obs_dim, 9);
  auto s = task.make_state();
  // [rough, wet, extra-dry] after the gait, per terrain 0..5, at reset and after a step.
  const float want[6][3] = {{0, 0, 0}, {0, 1, 0}, {0, 0, 1}, {1, 0, 0}, {1, 1, 0}, {1, 0, 1}};
  for (int t = 0; t < 6; ++t) {
    float obs[9], act[2] = {0.f, 0.f};
    task.reset_on(*s, 7, t, obs);
    EXPECT_FLOAT_EQ(obs[4], 1.f / 150.f) << "terrain " << t;  // the gait stays at 4, 5
    for (int i = 0; i < 3; ++i) EXPECT_EQ(obs[6 + i], want[t][i]) << "terrain " << t << " entry " << i;
    task.step(*s, act, obs);
    for (int i = 0; i < 3; ++i) EXPECT_EQ(obs[6 + i], want[t][i]) << "terrain " << t << " after a step";
  }
}
