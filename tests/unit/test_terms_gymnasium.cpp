// The task of terms against Gymnasium's definitions: HalfCheetah-, Humanoid-, Hopper-, Walker2d- and
// Ant-v4 as shipped configs of terms, each step's observation, reward and termination read back from
// mjData as Gymnasium's Python computes them, and its reset noise.
#include <gtest/gtest.h>
#include <mujoco/mujoco.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <random>
#include <string>
#include <vector>

#include "task.h"
#include "terms/terms_task.h"
#include "terms_testing.h"

namespace farm::robots::terms {
namespace {

TEST(TermsTask, HalfCheetahIsGymnasiumsV4) {
  Cheetah c;
  EXPECT_EQ(c.task->spec().obs_dim, 17);
  EXPECT_EQ(c.task->spec().act_dim, 6);
  EXPECT_EQ(c.task->spec().max_episode_steps, 1000);
  EXPECT_DOUBLE_EQ(c.task->agent_dt(), 0.05);
  const std::vector<float> a = {0.5f, -0.3f, 0.9f, -1.0f, 0.2f, 0.0f};
  double ctrl = 0;
  for (float x : a) ctrl += double(x) * x;
  for (int t = 0; t < 50; ++t) {
    const double x_before = c.s().data->qpos[0];
    const StepResult r = c.task->step(*c.state, a.data(), c.obs.data());
    const mjData* d = c.s().data;
    // reward = forward_reward_weight * (x' - x) / dt - ctrl_cost_weight * |a|^2
    EXPECT_NEAR(r.reward, (d->qpos[0] - x_before) / 0.05 - 0.1 * ctrl, 1e-4) << "step " << t;
    EXPECT_FALSE(r.terminated);
    // obs = qpos[1:], qvel
    for (int i = 1; i < 9; ++i) EXPECT_FLOAT_EQ(c.obs[i - 1], float(d->qpos[i]));
    for (int i = 0; i < 9; ++i) EXPECT_FLOAT_EQ(c.obs[8 + i], float(d->qvel[i]));
  }
}

// Humanoid-v4's step, read back from mjData: observation qpos[2:], qvel, cinert, cvel,
// qfrc_actuator, cfrc_ext (mj_rnePostConstraint after the step), reward 1.25 x the centre of mass's
// x velocity + 5 - 0.1 x |data.ctrl|^2, termination when qpos[2] leaves [1, 2].
TEST(TermsTask, HumanoidIsGymnasiumsV4) {
  Shipped h("humanoid_sac.txtpb");
  const mjModel* m = h.m();
  ASSERT_EQ(m->nbody, 14);
  ASSERT_EQ(m->nq, 24);
  ASSERT_EQ(m->nv, 23);
  EXPECT_EQ(h.task->spec().obs_dim, 376);
  EXPECT_EQ(h.task->spec().act_dim, 17);
  EXPECT_EQ(h.task->spec().max_episode_steps, 1000);
  EXPECT_DOUBLE_EQ(h.task->agent_dt(), 0.015);
  mjData* copy = mj_makeData(m);
  bool contact_force = false, ended = false;
  int t = 0;
  for (; t < 300 && !ended; ++t) {
    const auto before = mass_center_of(m, h.d());
    const StepResult r = h.step(swing(17, t));
    const mjData* d = h.d();
    double ctrl = 0;
    for (int i = 0; i < m->nu; ++i) ctrl += d->ctrl[i] * d->ctrl[i];
    EXPECT_GT(ctrl, 0) << "step " << t;
    const double x_vel = (mass_center_of(m, d)[0] - before[0]) / 0.015;
    EXPECT_NEAR(r.reward, 1.25 * x_vel + 5.0 - 0.1 * ctrl, 1e-4) << "step " << t;
    EXPECT_EQ(r.terminated, !(d->qpos[2] >= 1.0 && d->qpos[2] <= 2.0)) << "step " << t << " z " << d->qpos[2];
    ended = r.terminated || r.truncated;
    // cfrc_ext as MuJoCo computes it for this state, on a copy.
    mj_copyData(copy, m, d);
    mju_zero(copy->cfrc_ext, 6 * m->nbody);
    mj_rnePostConstraint(m, copy);
    std::vector<double> want(d->qpos + 2, d->qpos + m->nq);
    want.insert(want.end(), d->qvel, d->qvel + m->nv);
    want.insert(want.end(), d->cinert, d->cinert + 10 * m->nbody);
    want.insert(want.end(), d->cvel, d->cvel + 6 * m->nbody);
    want.insert(want.end(), d->qfrc_actuator, d->qfrc_actuator + m->nv);
    want.insert(want.end(), copy->cfrc_ext, copy->cfrc_ext + 6 * m->nbody);
    ASSERT_EQ(want.size(), h.obs.size());
    for (size_t i = 0; i < want.size(); ++i)
      EXPECT_FLOAT_EQ(h.obs[i], float(want[i])) << "step " << t << " entry " << i;
    for (int i = 6; i < 6 * m->nbody; ++i) contact_force = contact_force || copy->cfrc_ext[i] != 0;
    // The values the terms read are not all zero: the check above compares something.
    double cinert = 0, cvel = 0, qfrc = 0;
    for (int i = 0; i < 10 * m->nbody; ++i) cinert += std::abs(d->cinert[i]);
    for (int i = 0; i < 6 * m->nbody; ++i) cvel += std::abs(d->cvel[i]);
    for (int i = 6; i < m->nv; ++i) qfrc += std::abs(d->qfrc_actuator[i]);
    EXPECT_GT(cinert * cvel * qfrc, 0) << "step " << t;
  }
  mj_deleteData(copy);
  EXPECT_TRUE(contact_force) << "no contact force in " << t << " steps";
  EXPECT_TRUE(ended) << "the humanoid did not fall below z 1 in " << t << " steps";
  EXPECT_GT(t, 5);
}

// Gymnasium v4's locomotion tasks, each step read back from mjData as its Python computes it.
struct Before {
  std::vector<double> qpos, xpos;  // before the step
};
struct Gym {
  std::vector<double> obs;
  double reward = 0;
  bool terminated = false;
};
using GymStep = std::function<Gym(const mjModel*, const mjData*, const Before&, const std::vector<float>&)>;

double sum_sq(const std::vector<float>& a) {
  double s = 0;
  for (float x : a) s += double(x) * x;
  return s;
}

// Gymnasium's reset_model over 200 resets: every qpos entry is init_qpos (the model's qpos0) plus
// U(-scale, scale); every qvel entry U(-scale, scale), or scale x N(0, 1) where `normal_qvel`.
// The observation the reset returns is `gym`'s of the reset state.
void expect_reset_noise(Shipped& s, double scale, bool normal_qvel, const GymStep& gym) {
  const mjModel* m = s.m();
  // A free joint's quaternion: MuJoCo 2.2.2's mj_forward normalizes it in qpos in place after the
  // noise, so its entries are checked as a unit quaternion moved off qpos0's, not by the bound.
  std::vector<bool> quat(m->nq, false);
  for (int j = 0; j < m->njnt; ++j)
    if (m->jnt_type[j] == mjJNT_FREE)
      for (int k = 3; k < 7; ++k) quat[m->jnt_qposadr[j] + k] = true;
  int plain = 0;
  for (int i = 0; i < m->nq; ++i) plain += quat[i] ? 0 : 1;
  double qpos_sq = 0, qvel_sq = 0;
  bool qvel_beyond = false;
  for (uint64_t seed = 0; seed < 200; ++seed) {
    s.task->reset(*s.state, seed, s.obs.data());
    const mjData* d = s.d();
    double norm_sq = 0, moved = 0;
    for (int i = 0; i < m->nq; ++i) {
      if (quat[i]) {
        norm_sq += d->qpos[i] * d->qpos[i];
        moved += std::abs(d->qpos[i] - m->qpos0[i]);
      }
    }
    if (plain < m->nq) {
      EXPECT_NEAR(norm_sq, 1.0, 1e-12) << "seed " << seed;
      EXPECT_GT(moved, 0) << "seed " << seed;
    }
    for (int i = 0; i < m->nq; ++i) {
      if (quat[i]) continue;
      const double e = d->qpos[i] - m->qpos0[i];
      EXPECT_LE(std::abs(e), scale) << "seed " << seed << " qpos " << i;
      qpos_sq += e * e;
    }
    for (int i = 0; i < m->nv; ++i) {
      const double e = d->qvel[i];
      if (!normal_qvel) EXPECT_LE(std::abs(e), scale) << "seed " << seed << " qvel " << i;
      qvel_beyond = qvel_beyond || std::abs(e) > scale;
      qvel_sq += e * e;
    }
    const Gym want = gym(m, d, {}, {});
    ASSERT_EQ(want.obs.size(), s.obs.size());
    for (size_t i = 0; i < want.obs.size(); ++i)
      EXPECT_FLOAT_EQ(s.obs[i], float(want.obs[i])) << "seed " << seed << " entry " << i;
  }
  // The spread: U(-scale, scale) has standard deviation scale / sqrt(3), scale x N(0, 1) scale.
  const double uniform = scale / std::sqrt(3.0), qvel_sd = normal_qvel ? scale : uniform;
  EXPECT_NEAR(std::sqrt(qpos_sq / (200.0 * plain)), uniform, 0.1 * uniform);
  EXPECT_NEAR(std::sqrt(qvel_sq / (200.0 * m->nv)), qvel_sd, 0.1 * qvel_sd);
  EXPECT_EQ(qvel_beyond, normal_qvel);
}

struct Tally {
  int terminated = 0;
  int clipped = 0;  // steps after which some |qvel| is above 10
  int fast = 0;     // steps after which some |qvel| is above 100
};

// Steps the task with actions uniform in [-1, 1] (seeded), resetting after each termination, and
// compares every step's observation, reward (within float rounding) and termination with `gym`'s.
// `kick`, where given, changes the state before a step (the step is still compared whole).
Tally expect_steps_as_gym(Shipped& s, int steps, const GymStep& gym,
                          const std::function<void(mjData*, int)>& kick = nullptr) {
  const mjModel* m = s.m();
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> uniform(-1.f, 1.f);
  Tally n;
  uint64_t seed = 1000;
  for (int t = 0; t < steps; ++t) {
    std::vector<float> a(s.task->spec().act_dim);
    for (float& x : a) x = uniform(rng);
    if (kick) kick(s.state->data, t);
    const mjData* d = s.d();
    const Before before{{d->qpos, d->qpos + m->nq}, {d->xpos, d->xpos + 3 * m->nbody}};
    const StepResult r = s.step(a);
    const Gym want = gym(m, d, before, a);
    if (want.obs.size() != s.obs.size()) {
      ADD_FAILURE() << "observation size " << s.obs.size() << ", Gymnasium's " << want.obs.size();
      return n;
    }
    for (size_t i = 0; i < want.obs.size(); ++i)
      EXPECT_FLOAT_EQ(s.obs[i], float(want.obs[i])) << "step " << t << " entry " << i;
    EXPECT_NEAR(r.reward, want.reward, 1e-5 * std::max(1.0, std::abs(want.reward))) << "step " << t;
    EXPECT_EQ(r.terminated, want.terminated) << "step " << t;
    EXPECT_FALSE(r.truncated) << "step " << t;
    const double speed = largest_state(m, d, m->nq);
    n.clipped += speed > 10 ? 1 : 0;
    n.fast += speed > 100 ? 1 : 0;
    if (r.terminated) {
      ++n.terminated;
      s.task->reset(*s.state, seed++, s.obs.data());
    }
  }
  return n;
}

// Hopper-v4 and Walker2d-v4: obs qpos[1:], clip(qvel, -10, 10); reward (x' - x) / dt of qpos[0]
// + 1 - 1e-3 |a|^2; healthy z = qpos[1] and angle = qpos[2] strictly inside their ranges, and for
// Hopper every entry of state_vector()[2:] strictly inside (-100, 100).
Gym planar_v4(const mjModel* m, const mjData* d, const Before& b, const std::vector<float>& a, double z_min,
              double z_max, double angle, bool state_range) {
  Gym g;
  g.obs.assign(d->qpos + 1, d->qpos + m->nq);
  for (int i = 0; i < m->nv; ++i) g.obs.push_back(std::clamp(d->qvel[i], -10.0, 10.0));
  if (b.qpos.empty()) return g;  // after a reset: the observation alone
  g.reward = (d->qpos[0] - b.qpos[0]) / 0.008 + 1.0 - 1e-3 * sum_sq(a);
  std::vector<double> state(d->qpos, d->qpos + m->nq);
  state.insert(state.end(), d->qvel, d->qvel + m->nv);
  bool healthy_state = true;
  for (size_t i = 2; i < state.size() && state_range; ++i)
    healthy_state = healthy_state && -100 < state[i] && state[i] < 100;
  const double z = d->qpos[1], ang = d->qpos[2];
  g.terminated = !(healthy_state && z_min < z && z < z_max && -angle < ang && ang < angle);
  return g;
}

TEST(TermsTask, HopperIsGymnasiumsV4) {
  Shipped h("hopper_sac.txtpb");
  const mjModel* m = h.m();
  ASSERT_EQ(m->nq, 6);
  ASSERT_EQ(m->nv, 6);
  EXPECT_EQ(m->opt.integrator, mjINT_RK4);
  EXPECT_EQ(h.task->spec().obs_dim, 11);
  EXPECT_EQ(h.task->spec().act_dim, 3);
  EXPECT_EQ(h.task->spec().max_episode_steps, 1000);
  EXPECT_DOUBLE_EQ(h.task->agent_dt(), 0.008);
  const GymStep gym = [](const mjModel* m, const mjData* d, const Before& b, const std::vector<float>& a) {
    return planar_v4(m, d, b, a, 0.7, INFINITY, 0.2, true);
  };
  expect_reset_noise(h, 5e-3, false, gym);
  // Random actions end episodes on the angle and the height long before any speed reaches 10: now
  // and then the torso is pushed forward at 12 m/s (the observation's clip) or at 150 m/s (out of
  // healthy_state_range).
  const Tally n = expect_steps_as_gym(h, 400, gym, [](mjData* d, int t) {
    if (t % 30 == 10) d->qvel[0] = 12.0;
    if (t % 90 == 70) d->qvel[0] = 150.0;
  });
  EXPECT_GE(n.terminated, 5) << "random actions ended few episodes";
  EXPECT_GT(n.clipped, 0) << "no |qvel| above 10: the clip was not exercised";
  EXPECT_GT(n.fast, 0) << "no |qvel| above 100: healthy_state_range was not exercised";
}

TEST(TermsTask, Walker2dIsGymnasiumsV4) {
  Shipped w("walker2d_sac.txtpb");
  const mjModel* m = w.m();
  ASSERT_EQ(m->nq, 9);
  ASSERT_EQ(m->nv, 9);
  EXPECT_EQ(m->opt.integrator, mjINT_RK4);
  EXPECT_EQ(w.task->spec().obs_dim, 17);
  EXPECT_EQ(w.task->spec().act_dim, 6);
  EXPECT_EQ(w.task->spec().max_episode_steps, 1000);
  EXPECT_DOUBLE_EQ(w.task->agent_dt(), 0.008);
  const GymStep gym = [](const mjModel* m, const mjData* d, const Before& b, const std::vector<float>& a) {
    return planar_v4(m, d, b, a, 0.8, 2.0, 1.0, false);
  };
  expect_reset_noise(w, 5e-3, false, gym);
  const Tally n = expect_steps_as_gym(w, 400, gym);
  EXPECT_GE(n.terminated, 3) << "random actions ended few episodes";
  EXPECT_GT(n.clipped, 0) << "no |qvel| above 10: the clip was not exercised";
}

// Ant-v4 (use_contact_forces False): obs qpos[2:], qvel; reward the x velocity of the torso body's
// xpos over the step + 1 - 0.5 |a|^2; healthy when the state is finite and 0.2 <= qpos[2] <= 1.
TEST(TermsTask, AntIsGymnasiumsV4) {
  Shipped ant("ant_sac.txtpb");
  const mjModel* m = ant.m();
  ASSERT_EQ(m->nq, 15);
  ASSERT_EQ(m->nv, 14);
  EXPECT_EQ(m->opt.integrator, mjINT_RK4);
  EXPECT_EQ(ant.task->spec().obs_dim, 27);
  EXPECT_EQ(ant.task->spec().act_dim, 8);
  EXPECT_EQ(ant.task->spec().max_episode_steps, 1000);
  EXPECT_DOUBLE_EQ(ant.task->agent_dt(), 0.05);
  const int torso = mj_name2id(m, mjOBJ_BODY, "torso");
  ASSERT_GT(torso, 0);
  const GymStep gym = [torso](const mjModel* m, const mjData* d, const Before& b, const std::vector<float>& a) {
    Gym g;
    g.obs.assign(d->qpos + 2, d->qpos + m->nq);
    g.obs.insert(g.obs.end(), d->qvel, d->qvel + m->nv);
    if (b.qpos.empty()) return g;
    g.reward = (d->xpos[3 * torso] - b.xpos[3 * torso]) / 0.05 + 1.0 - 0.5 * sum_sq(a);
    bool finite = true;
    for (int i = 0; i < m->nq; ++i) finite = finite && std::isfinite(d->qpos[i]);
    for (int i = 0; i < m->nv; ++i) finite = finite && std::isfinite(d->qvel[i]);
    g.terminated = !(finite && 0.2 <= d->qpos[2] && d->qpos[2] <= 1.0);
    return g;
  };
  expect_reset_noise(ant, 0.1, true, gym);
  // Random actions seldom take the torso out of [0.2, 1]: every 40 steps an upward kick of 4 m/s
  // throws it above 1 a few steps later, so terminations are compared too.
  const Tally n = expect_steps_as_gym(ant, 300, gym, [](mjData* d, int t) {
    if (t % 40 == 20) d->qvel[2] = 4.0;
  });
  EXPECT_GE(n.terminated, 5) << "the kicks ended few episodes";
}

}  // namespace
}  // namespace farm::robots::terms
