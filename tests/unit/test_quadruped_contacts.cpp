// Quadrupeds of the MushroomRL paper (Unitree A1, Honey Badger, Silver Badger): contact queries of the legged
// layer and what counts as a fall, on the real MuJoCo models.
#include <gtest/gtest.h>
#include <mujoco/mujoco.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <memory>
#include <random>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "embedded_mjcf.h"
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

TEST(Quadruped, AFallCostsTheTerminationTermAfterTheClip) {
  // The same fall twice, without and with legged_gym's termination term: the second step's reward
  // is the first's (clipped at 0) plus termination x policy step, so it is negative.
  std::vector<float> rewards;
  for (const double scale : {0.0, -50.0}) {
    config::TaskConfig c;
    c.set_name("a1");
    auto* l = legged_of(c);
    l->set_noise_level(0);
    l->set_push_interval_s(0);
    l->mutable_reward()->set_termination(scale);
    auto task = std::unique_ptr<QuadrupedTask>(static_cast<QuadrupedTask*>(make_task(c).release()));
    auto s = task->make_state();
    auto& qs = static_cast<QuadrupedState&>(*s);
    std::vector<float> obs(task->spec().obs_dim), zero(task->spec().act_dim, 0.f);
    task->reset(*s, 5, obs.data());
    const StepResult standing = task->step(*s, zero.data(), obs.data());
    EXPECT_FALSE(standing.terminated);
    const double z = 0.03;
    legged::write_property(qs.model, qs.data, legged::Property::kBodyHeight, task->trunk_body(), &z);
    mj_forward(qs.model, qs.data);
    const StepResult r = task->step(*s, zero.data(), obs.data());
    ASSERT_TRUE(r.terminated);
    rewards.push_back(r.reward);
  }
  EXPECT_GE(rewards[0], 0.f);
  EXPECT_NEAR(rewards[1], rewards[0] - 50.0 * 0.02, 1e-6);
  EXPECT_LT(rewards[1], 0.f);
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

// ---- The collision lists (<contact> pairs, collision="predefined"; docs/record/quadrupeds.md, "The A1's
// physics step"), each model against the same MJCF without its list, i.e. on MuJoCo's broad phase. ----

namespace {

struct ModelDeleter {
  void operator()(mjModel* m) const { mj_deleteModel(m); }
};
using ModelPtr = std::unique_ptr<mjModel, ModelDeleter>;

ModelPtr without_list(const std::string& robot) {
  const std::string path = "quadruped/" + robot + ".xml";
  return ModelPtr(load_model_from_text(path, without_collision_list(embedded_text(path))));
}

std::pair<int, int> ordered(int a, int b) { return {std::min(a, b), std::max(a, b)}; }

// Geom pairs of the model's current contacts.
std::set<std::pair<int, int>> contact_pairs(const mjData* d) {
  std::set<std::pair<int, int>> out;
  for (int i = 0; i < d->ncon; ++i) out.insert(ordered(d->contact[i].geom1, d->contact[i].geom2));
  return out;
}

std::string body_of(const mjModel* m, int geom) { return mj_id2name(m, mjOBJ_BODY, m->geom_bodyid[geom]); }

// Body pairs (names in sorted order) a robot's list leaves out because they cannot touch: the
// A1's hip housings with each other and with their own calves (a1.xml shows why); the Badgers'
// lists leave nothing out.
std::set<std::pair<std::string, std::string>> cannot_touch(const std::string& robot) {
  std::set<std::pair<std::string, std::string>> out;
  if (robot != "a1") return out;
  for (const char* a : {"FL", "FR", "RL", "RR"}) {
    out.insert({std::string(a) + "_calf", std::string(a) + "_hip"});
    for (const char* b : {"FL", "FR", "RL", "RR"})
      if (std::string(a) < b) out.insert({std::string(a) + "_hip", std::string(b) + "_hip"});
  }
  return out;
}

}  // namespace

TEST(Quadruped, CollisionListHoldsEveryPairThatCanTouch) {
  for (const char* name : kRobots) {
    SCOPED_TRACE(name);
    const ModelPtr old = without_list(name);
    auto task = quiet_task(name);
    const mjModel* m = task->model();
    ASSERT_EQ(m->opt.collision, mjCOL_PAIR);
    ASSERT_EQ(old->opt.collision, mjCOL_ALL);
    ASSERT_EQ(old->npair, 0);
    std::set<std::pair<int, int>> listed;
    for (int p = 0; p < m->npair; ++p) {
      EXPECT_TRUE(listed.insert(ordered(m->pair_geom1[p], m->pair_geom2[p])).second) << "pair " << p << " twice";
      // The pair's contact is the one MuJoCo makes for these two geoms without the list.
      const int g1 = m->pair_geom1[p], g2 = m->pair_geom2[p];
      EXPECT_EQ(m->pair_dim[p], std::max(m->geom_condim[g1], m->geom_condim[g2]));
      EXPECT_EQ(m->pair_margin[p], 0.0);
      EXPECT_EQ(m->pair_gap[p], 0.0);
      for (int k = 0; k < mjNREF; ++k) {
        EXPECT_EQ(m->geom_solref[mjNREF * g1 + k], m->geom_solref[mjNREF * g2 + k]);
        EXPECT_EQ(m->pair_solref[mjNREF * p + k], m->geom_solref[mjNREF * g1 + k]);
      }
      for (int k = 0; k < mjNIMP; ++k) {
        EXPECT_EQ(m->geom_solimp[mjNIMP * g1 + k], m->geom_solimp[mjNIMP * g2 + k]);
        EXPECT_EQ(m->pair_solimp[mjNIMP * p + k], m->geom_solimp[mjNIMP * g1 + k]);
      }
      const double* f = m->pair_friction + 5 * p;
      const double* f1 = m->geom_friction + 3 * g1;
      const double* f2 = m->geom_friction + 3 * g2;
      EXPECT_EQ(f[0], std::max(f1[0], f2[0]));
      EXPECT_EQ(f[2], std::max(f1[1], f2[1]));
      EXPECT_EQ(f[4], std::max(f1[2], f2[2]));
    }
    // Every pair MuJoCo's own filters let collide (different bodies, not a body and its parent,
    // bitmasks) is listed, but for the body pairs that cannot touch.
    const auto left_alone = cannot_touch(name);
    int candidates = 0, left_out = 0;
    for (int g1 = 0; g1 < old->ngeom; ++g1) {
      for (int g2 = g1 + 1; g2 < old->ngeom; ++g2) {
        const int b1 = old->geom_bodyid[g1], b2 = old->geom_bodyid[g2];
        if (b1 == b2 || (b1 && b2 && (old->body_parentid[b1] == b2 || old->body_parentid[b2] == b1))) continue;
        if (!(old->geom_contype[g1] & old->geom_conaffinity[g2]) &&
            !(old->geom_contype[g2] & old->geom_conaffinity[g1]))
          continue;
        ++candidates;
        const std::string n1 = body_of(old.get(), g1), n2 = body_of(old.get(), g2);
        if (left_alone.count({std::min(n1, n2), std::max(n1, n2)})) {
          ++left_out;
          EXPECT_FALSE(listed.count({g1, g2})) << n1 << " / " << n2;
          continue;
        }
        EXPECT_TRUE(listed.count({g1, g2})) << "not in the collision list: " << mj_id2name(old.get(), mjOBJ_GEOM, g1)
                                            << " / " << mj_id2name(old.get(), mjOBJ_GEOM, g2);
      }
    }
    // A1: housing-housing, housing-calf and housing-foot.
    EXPECT_EQ(left_out, std::string(name) == "a1" ? 6 + 4 * 2 : 0);
    EXPECT_EQ(int(listed.size()), candidates - left_out);

    // The task re-mixes the pairs after randomizing the feet's friction: below the floor's 1 the
    // floor's wins, as it does for geom contacts.
    auto rtask = quiet_task(name, /*randomize=*/true);
    auto s = rtask->make_state();
    auto& qs = static_cast<QuadrupedState&>(*s);
    std::vector<float> obs(rtask->spec().obs_dim);
    bool below = false, above = false;
    for (uint64_t seed = 1; seed <= 40; ++seed) {
      rtask->reset(*s, seed, obs.data());
      for (int p = 0; p < qs.model->npair; ++p) {
        const int g1 = qs.model->pair_geom1[p], g2 = qs.model->pair_geom2[p];
        const double want = std::max(qs.model->geom_friction[3 * g1], qs.model->geom_friction[3 * g2]);
        ASSERT_EQ(qs.model->pair_friction[5 * p], want);
        ASSERT_EQ(qs.model->pair_friction[5 * p + 1], want);
      }
      const int foot = rtask->feet().geoms[0];
      below |= qs.model->geom_friction[3 * foot] < 1.0;
      above |= qs.model->geom_friction[3 * foot] > 1.0;
    }
    EXPECT_TRUE(below && above) << "the seeds drew foot friction on one side of the floor's only";
  }
}

TEST(Quadruped, CollisionListDetectsEveryContactOfTheFullModel) {
  // Random poses over the whole joint ranges, the trunk tilted at random and lowered towards the
  // floor: the list finds exactly the contacts (geom pairs) MuJoCo's broad phase finds. Among
  // them, every kind the task reads (feet, calves, thighs, hip housings and trunk on the floor)
  // and self-collisions between legs and with the trunk.
  for (const char* name : kRobots) {
    SCOPED_TRACE(name);
    const ModelPtr old = without_list(name);
    auto task = quiet_task(name);
    const mjModel* m = task->model();
    mjData* d_new = mj_makeData(m);
    mjData* d_old = mj_makeData(old.get());
    std::mt19937_64 rng(5);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    const int floor = task->floor().geoms[0];
    auto in = [](const legged::CollisionGroup& g, int geom) {
      return std::find(g.geoms.begin(), g.geoms.end(), geom) != g.geoms.end();
    };
    std::vector<int> trunk_boxes;  // the trunk group less the hip housings
    for (int g : task->trunk().geoms)
      if (m->geom_type[g] == mjGEOM_BOX) trunk_boxes.push_back(g);
    auto is_trunk_box = [&](int g) {
      return std::find(trunk_boxes.begin(), trunk_boxes.end(), g) != trunk_boxes.end();
    };
    int feet = 0, legs = 0, hips = 0, trunk = 0, self_legs = 0, self_trunk = 0, mismatches = 0;
    const int kPoses = 20000;
    for (int k = 0; k < kPoses; ++k) {
      std::vector<double> q(m->nq, 0.0);
      q[2] = 0.05 + 0.35 * u(rng);
      double quat[4] = {1, 0.6 * (u(rng) - 0.5), 0.6 * (u(rng) - 0.5), 2 * (u(rng) - 0.5)};
      mju_normalize4(quat);
      std::copy(quat, quat + 4, q.begin() + 3);
      for (int j = 1; j < m->njnt; ++j)
        q[m->jnt_qposadr[j]] = m->jnt_range[2 * j] + u(rng) * (m->jnt_range[2 * j + 1] - m->jnt_range[2 * j]);
      for (auto [mm, dd] : {std::pair<const mjModel*, mjData*>{m, d_new}, {old.get(), d_old}}) {
        std::copy(q.begin(), q.end(), dd->qpos);
        mj_kinematics(mm, dd);
        mj_collision(mm, dd);
      }
      const auto got = contact_pairs(d_new), want = contact_pairs(d_old);
      if (got != want && ++mismatches <= 5)
        ADD_FAILURE() << "pose " << k << ": the list found " << got.size() << " contact pairs, the broad phase "
                      << want.size();
      for (const auto& [g1, g2] : want) {
        const int other = g1 == floor ? g2 : g2 == floor ? g1 : -1;
        if (other >= 0) {
          feet += in(task->feet(), other);
          legs += in(task->legs(), other);
          hips += in(task->trunk(), other) && !is_trunk_box(other);
          trunk += is_trunk_box(other);
        } else if (is_trunk_box(g1) || is_trunk_box(g2)) {
          ++self_trunk;
        } else {
          ++self_legs;
        }
      }
    }
    mj_deleteData(d_new);
    mj_deleteData(d_old);
    EXPECT_EQ(mismatches, 0);
    // The poses reached every kind of contact many times over, so a pair cut from the list that
    // the task or the dynamics needs would have shown above.
    EXPECT_GT(feet, 1000);
    EXPECT_GT(legs, 1000);
    EXPECT_GT(hips, 100);
    EXPECT_GT(trunk, 100);
    EXPECT_GT(self_legs, 100);
    EXPECT_GT(self_trunk, 100);
    std::printf(
        "%s, contacts over %d poses: feet-floor %d, thigh/calf-floor %d, hip-floor %d, trunk-floor %d, "
        "leg-leg %d, trunk-leg %d\n",
        name, kPoses, feet, legs, hips, trunk, self_legs, self_trunk);
  }
}

TEST(Quadruped, DynamicsUnchangedByTheCollisionList) {
  // The shipped task (randomization on, noise, pushes) with full-range random actions, episode
  // after episode (most end in falls), on the model with the list and on the model without it:
  // the same rewards and ends, and states that differ by rounding only. The list changes only the
  // order in which MuJoCo finds the contacts, which the Newton solver's result does not depend on
  // beyond rounding; while the robot tumbles, rounding differences grow. So a third run, the
  // model without the list with MuJoCo's sparse instead of dense Jacobian (a change of rounding
  // alone), sets the scale: in each episode the largest state difference of the list (m, rad,
  // m/s, rad/s, any coordinate) stays below 1e-6 or below 10 times the sparse run's. Measured
  // here: at most 8.8e-10 for the A1; 1.6e-4 in one tumbling Honey Badger episode where the
  // sparse Jacobian alone gives 1.5e-4.
  for (const char* name : kRobots) {
    SCOPED_TRACE(name);
    const ModelPtr old = without_list(name);
    ModelPtr sparse(mj_copyModel(nullptr, old.get()));
    sparse->opt.jacobian = mjJAC_SPARSE;
    config::TaskConfig c;
    c.set_name(name);
    auto base = make_task(c);
    const auto& task = static_cast<const QuadrupedTask&>(*base);
    auto s_new = task.make_state(), s_old = task.make_state(), s_ref = task.make_state();
    auto& qn = static_cast<QuadrupedState&>(*s_new);
    auto& qo = static_cast<QuadrupedState&>(*s_old);
    auto& qr = static_cast<QuadrupedState&>(*s_ref);
    use_model(task, qo, old.get());
    use_model(task, qr, sparse.get());
    ASSERT_EQ(qn.model->opt.collision, mjCOL_PAIR);
    ASSERT_EQ(qo.model->opt.collision, mjCOL_ALL);
    std::vector<float> on(task.spec().obs_dim), oo(task.spec().obs_dim), orf(task.spec().obs_dim),
        a(task.spec().act_dim);
    std::mt19937_64 rng(11);
    std::uniform_real_distribution<float> u(-1.f, 1.f);
    uint64_t seed = 100;
    auto reset_all = [&] {
      task.reset(*s_new, seed, on.data());
      task.reset(*s_old, seed, oo.data());
      task.reset(*s_ref, seed, orf.data());
    };
    auto difference = [](const QuadrupedState& x, const QuadrupedState& y) {
      double d = 0;
      for (int i = 0; i < x.model->nq; ++i) d = std::max(d, std::abs(x.data->qpos[i] - y.data->qpos[i]));
      for (int i = 0; i < x.model->nv; ++i) d = std::max(d, std::abs(x.data->qvel[i] - y.data->qvel[i]));
      return d;
    };
    reset_all();
    double episode_list = 0, episode_ref = 0, worst = 0;
    int episodes = 0, contacts = 0;
    const int kSteps = 3000;
    for (int k = 0; k < kSteps; ++k) {
      for (auto& x : a) x = u(rng);
      const StepResult rn = task.step(*s_new, a.data(), on.data());
      const StepResult ro = task.step(*s_old, a.data(), oo.data());
      const StepResult rr = task.step(*s_ref, a.data(), orf.data());
      episode_list = std::max(episode_list, difference(qn, qo));
      episode_ref = std::max(episode_ref, difference(qr, qo));
      ASSERT_EQ(rn.terminated, ro.terminated) << "env step " << k;
      ASSERT_EQ(rn.truncated, ro.truncated) << "env step " << k;
      ASSERT_EQ(rr.terminated || rr.truncated, ro.terminated || ro.truncated) << "env step " << k;
      ASSERT_NEAR(rn.reward, ro.reward, 1e-3) << "env step " << k;
      contacts += qn.data->ncon;
      if (ro.terminated || ro.truncated || k + 1 == kSteps) {
        EXPECT_LE(episode_list, std::max(1e-6, 10 * episode_ref))
            << "episode " << episodes << " ending at env step " << k << ": the sparse Jacobian alone differs by "
            << episode_ref;
        worst = std::max(worst, episode_list);
        episode_list = episode_ref = 0;
        ++seed;
        ++episodes;
        reset_all();
      }
    }
    EXPECT_GT(episodes, 2) << "the rollout should cover falls and resets";
    EXPECT_GT(contacts, kSteps);
    std::printf("%s: %d env steps, %d episodes: largest state difference %.3g\n", name, kSteps, episodes, worst);
  }
}
