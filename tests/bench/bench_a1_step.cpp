// Where the time of a quadruped's physics step goes, for the shipped model and for the same model
// without its collision list (the <contact> pairs and collision="predefined" cut, i.e. MuJoCo's
// broad phase over all bodies, as before; tests/unit/quadruped_testing.h):
// MuJoCo's stage timers per mj_step, contacts, constraint rows and solver iterations per step,
// the geom pairs the collision stage can test, and env steps/s (4 physics steps each).
// Usage: bench_a1_step [--robot a1|honey_badger|silver_badger] [--seconds S] [--rounds N]
//        bench_a1_step --mjcf FILE [--seconds S] [--rounds N]
// --mjcf profiles another quadruped's model file the same way without a task (e.g.
// tests/data/menagerie_unitree_a1/a1_collision.xml, whose actuators are position servos): from
// its first keyframe, every 4 physics steps the controls are the keyframe's plus U(-0.5, 0.5)
// (targets +-0.5 rad about the home pose, as the task's random actions give), back to the
// keyframe when body 1 (the trunk) is below 0.12 m or after 1,000 env steps.
// The profile runs the task itself (PD control on every physics step, random actions in
// [-0.5, 0.5], episodes reset as they end); the raw rate is bench_worker's: a plain mj_step loop
// from the state 10 zero-action env steps after the task's reset, controls as the task left them.
#include <mujoco/mujoco.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include "../unit/quadruped_testing.h"
#include "bench_options.h"
#include "embedded_mjcf.h"
#include "quadruped/quadruped_task.h"
#include "quadruped_rate.h"
#include "task.h"

namespace {

using Clock = std::chrono::steady_clock;
using farm::robots::quadruped::QuadrupedState;
using farm::robots::quadruped::QuadrupedTask;
namespace ts = farm::robots::quadruped::test_support;

double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

// MuJoCo 2.2.2 records its stage timers only through this callback (units: microseconds here).
mjtNum now_us() { return mjtNum(std::chrono::duration<double, std::micro>(Clock::now().time_since_epoch()).count()); }

struct ModelDeleter {
  void operator()(mjModel* m) const { mj_deleteModel(m); }
};
using ModelPtr = std::unique_ptr<mjModel, ModelDeleter>;

bool excluded(const mjModel* m, int b1, int b2) {
  for (int i = 0; i < m->nexclude; ++i) {
    const int s = m->exclude_signature[i], e1 = (s >> 16) - 1, e2 = (s & 0xFFFF) - 1;  // (b1+1)<<16 + b2+1
    if ((e1 == b1 && e2 == b2) || (e1 == b2 && e2 == b1)) return true;
  }
  return false;
}

// Geom pairs MuJoCo 2.2.2's collision stage may hand to a collision function. With
// collision="predefined", the model's <pair> list; otherwise what its broad phase draws from:
// geoms of different weld bodies, not a body and its parent (filterparent), matching
// contype/conaffinity bitmasks, body pair not excluded. Which of them reach the collision
// function on a step depends on the bounding spheres (near_pairs).
std::vector<std::pair<int, int>> candidate_pairs(const mjModel* m) {
  std::vector<std::pair<int, int>> out;
  if (m->opt.collision == mjCOL_PAIR) {
    for (int p = 0; p < m->npair; ++p) out.emplace_back(m->pair_geom1[p], m->pair_geom2[p]);
    return out;
  }
  for (int g1 = 0; g1 < m->ngeom; ++g1) {
    for (int g2 = g1 + 1; g2 < m->ngeom; ++g2) {
      const int b1 = m->body_weldid[m->geom_bodyid[g1]], b2 = m->body_weldid[m->geom_bodyid[g2]];
      if (b1 == b2) continue;
      const int p1 = m->body_weldid[m->body_parentid[b1]], p2 = m->body_weldid[m->body_parentid[b2]];
      if (!(m->opt.disableflags & mjDSBL_FILTERPARENT) && b1 && b2 && (b1 == p2 || b2 == p1)) continue;
      if (!(m->geom_contype[g1] & m->geom_conaffinity[g2]) && !(m->geom_contype[g2] & m->geom_conaffinity[g1]))
        continue;
      if (excluded(m, m->geom_bodyid[g1], m->geom_bodyid[g2])) continue;
      out.emplace_back(g1, g2);
    }
  }
  return out;
}

// Candidate pairs whose bounding spheres (for a plane: the half-space) overlap in the current state.
int near_pairs(const mjModel* m, const mjData* d, const std::vector<std::pair<int, int>>& pairs) {
  int n = 0;
  for (const auto& [g1, g2] : pairs) {
    const mjtNum* x1 = d->geom_xpos + 3 * g1;
    const mjtNum* x2 = d->geom_xpos + 3 * g2;
    bool near;
    if (m->geom_type[g1] == mjGEOM_PLANE || m->geom_type[g2] == mjGEOM_PLANE) {
      const int p = m->geom_type[g1] == mjGEOM_PLANE ? g1 : g2, o = p == g1 ? g2 : g1;
      const mjtNum* mat = d->geom_xmat + 9 * p;
      const mjtNum* xo = d->geom_xpos + 3 * o;
      const mjtNum* xp = d->geom_xpos + 3 * p;
      const mjtNum dist = (xo[0] - xp[0]) * mat[2] + (xo[1] - xp[1]) * mat[5] + (xo[2] - xp[2]) * mat[8];
      near = dist <= m->geom_rbound[o];
    } else {
      const mjtNum r = m->geom_rbound[g1] + m->geom_rbound[g2];
      const mjtNum dx = x1[0] - x2[0], dy = x1[1] - x2[1], dz = x1[2] - x2[2];
      near = dx * dx + dy * dy + dz * dz <= r * r;
    }
    n += near;
  }
  return n;
}

struct Profile {
  double timer_us[mjNTIMER] = {};
  double steps = 0, ncon = 0, nefc = 0, iters = 0, near = 0;
  int max_iters = 0, max_ncon = 0, max_nefc = 0;
  uint64_t env_steps = 0, episodes = 0;
};

void add_timers(Profile& p, const mjData* d) {
  for (int t = 0; t < mjNTIMER; ++t) p.timer_us[t] += d->timer[t].duration;
}

// Runs the task on `model` with random actions for `seconds`, with the stage timers on.
Profile profile(const QuadrupedTask& task, const mjModel* model, double seconds) {
  auto s = task.make_state();
  auto& qs = static_cast<QuadrupedState&>(*s);
  ts::use_model(task, qs, model);
  const auto pairs = candidate_pairs(model);
  Profile p;
  qs.after_physics_step = [&] {
    const mjData* d = qs.data;
    p.steps += 1;
    p.ncon += d->ncon;
    p.nefc += d->nefc;
    p.iters += d->solver_iter;
    p.near += near_pairs(qs.model, d, pairs);
    p.max_iters = std::max(p.max_iters, d->solver_iter);
    p.max_ncon = std::max(p.max_ncon, d->ncon);
    p.max_nefc = std::max(p.max_nefc, d->nefc);
  };
  std::vector<float> obs(task.spec().obs_dim), a(task.spec().act_dim);
  std::mt19937_64 rng(1);
  std::uniform_real_distribution<float> u(-0.5f, 0.5f);
  uint64_t seed = 1;
  mjcb_time = now_us;
  task.reset(*s, seed++, obs.data());
  const auto t0 = Clock::now();
  do {
    for (int i = 0; i < 100; ++i) {
      for (auto& x : a) x = u(rng);
      const auto r = task.step(*s, a.data(), obs.data());
      ++p.env_steps;
      if (r.terminated || r.truncated) {
        add_timers(p, qs.data);  // mj_resetData clears them
        task.reset(*s, seed++, obs.data());
        ++p.episodes;
      }
    }
  } while (seconds_since(t0) < seconds);
  add_timers(p, qs.data);
  mjcb_time = nullptr;
  return p;
}

// Env steps/s of the task on `model`, random actions, timers off.
double task_rate(const QuadrupedTask& task, const mjModel* model, double seconds) {
  auto s = task.make_state();
  ts::use_model(task, static_cast<QuadrupedState&>(*s), model);
  return farm::bench::random_action_rate(task, *s, seconds);
}

// bench_worker's raw rate: mj_step alone from a state of the task, in env steps/s.
double raw_rate(const QuadrupedTask& task, const mjModel* model, double seconds) {
  auto s = task.make_state();
  auto& qs = static_cast<QuadrupedState&>(*s);
  ts::use_model(task, qs, model);
  std::vector<float> obs(task.spec().obs_dim), zero(task.spec().act_dim, 0.f);
  task.reset(*s, 1, obs.data());
  for (int k = 0; k < 10; ++k) task.step(*s, zero.data(), obs.data());
  mjData* d = mj_copyData(nullptr, qs.model, qs.data);
  uint64_t steps = 0;
  const auto t0 = Clock::now();
  double elapsed = 0;
  do {
    for (int i = 0; i < 10000; ++i) mj_step(qs.model, d);
    steps += 10000;
    elapsed = seconds_since(t0);
  } while (elapsed < seconds);
  mj_deleteData(d);
  return steps / elapsed / task.config().decimation();
}

// The --mjcf loop (see the top); with `p`, the stage timers on and the profile filled in.
double file_rate(const mjModel* m, double seconds, Profile* p) {
  mjData* d = mj_makeData(m);
  const auto pairs = candidate_pairs(m);
  std::mt19937_64 rng(1);
  std::uniform_real_distribution<double> u(-0.5, 0.5);
  auto reset = [&] {
    if (p) add_timers(*p, d);
    mj_resetDataKeyframe(m, d, 0);
    mj_forward(m, d);
  };
  reset();
  if (p) mjcb_time = now_us;
  uint64_t env_steps = 0, episode_steps = 0;
  const auto t0 = Clock::now();
  double elapsed = 0;
  do {
    for (int i = 0; i < 100; ++i) {
      for (int a = 0; a < m->nu; ++a) d->ctrl[a] = m->key_ctrl[a] + u(rng);
      for (int k = 0; k < 4; ++k) {
        mj_step(m, d);
        if (!p) continue;
        p->steps += 1;
        p->ncon += d->ncon;
        p->nefc += d->nefc;
        p->iters += d->solver_iter;
        p->near += near_pairs(m, d, pairs);
        p->max_iters = std::max(p->max_iters, d->solver_iter);
        p->max_ncon = std::max(p->max_ncon, d->ncon);
        p->max_nefc = std::max(p->max_nefc, d->nefc);
      }
      ++env_steps;
      if (++episode_steps >= 1000 || d->xpos[3 * 1 + 2] < 0.12) {
        reset();
        episode_steps = 0;
        if (p) ++p->episodes;
      }
    }
    elapsed = seconds_since(t0);
  } while (elapsed < seconds);
  if (p) {
    add_timers(*p, d);
    p->env_steps = env_steps;
    mjcb_time = nullptr;
  }
  mj_deleteData(d);
  return env_steps / elapsed;
}

// A seeded rollout of the task (random actions in [-0.5, 0.5], resets as episodes end) on `model`
// with its solver settings changed: Newton iterations per physics step, env steps/s, and the
// trajectory (qpos after every env step) for comparison with the unchanged settings.
struct SolverRun {
  double iters_per_step = 0, rate = 0;
  std::vector<double> qpos;
};
SolverRun solver_run(const QuadrupedTask& task, const mjModel* model, int solver, double tolerance, int env_steps) {
  ModelPtr m(mj_copyModel(nullptr, model));
  m->opt.solver = solver;
  m->opt.tolerance = tolerance;
  auto s = task.make_state();
  auto& qs = static_cast<QuadrupedState&>(*s);
  ts::use_model(task, qs, m.get());
  SolverRun out;
  double steps = 0;
  qs.after_physics_step = [&] {
    out.iters_per_step += qs.data->solver_iter;
    steps += 1;
  };
  std::vector<float> obs(task.spec().obs_dim), a(task.spec().act_dim);
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<float> u(-0.5f, 0.5f);
  uint64_t seed = 1;
  task.reset(*s, seed++, obs.data());
  const auto t0 = Clock::now();
  for (int k = 0; k < env_steps; ++k) {
    for (auto& x : a) x = u(rng);
    const auto r = task.step(*s, a.data(), obs.data());
    out.qpos.insert(out.qpos.end(), qs.data->qpos, qs.data->qpos + qs.model->nq);
    if (r.terminated || r.truncated) task.reset(*s, seed++, obs.data());
  }
  out.rate = env_steps / seconds_since(t0);
  out.iters_per_step /= steps;
  return out;
}

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

void print_profile(const char* label, const mjModel* m, const Profile& p) {
  const auto pairs = candidate_pairs(m);
  int floor_pairs = 0;
  for (const auto& [g1, g2] : pairs)
    floor_pairs += m->geom_type[g1] == mjGEOM_PLANE || m->geom_type[g2] == mjGEOM_PLANE;
  std::printf("\n[%s] %d geoms, %d bodies; collision %s; candidate geom pairs %zu (%d with the floor)\n", label,
              m->ngeom, m->nbody, m->opt.collision == mjCOL_PAIR ? "predefined (<pair> list only)" : "broad phase",
              pairs.size(), floor_pairs);
  std::printf("  %llu env steps, %.0f physics steps, %llu episodes\n", (unsigned long long)p.env_steps, p.steps,
              (unsigned long long)p.episodes);
  std::printf(
      "  per physics step: contacts %.2f (max %d), constraint rows %.1f (max %d), solver iterations %.2f "
      "(max %d), candidate pairs within bounding spheres %.2f\n",
      p.ncon / p.steps, p.max_ncon, p.nefc / p.steps, p.max_nefc, p.iters / p.steps, p.max_iters, p.near / p.steps);
  struct Row {
    const char* name;
    double us;
  };
  const double* t = p.timer_us;
  const double step = t[mjTIMER_STEP];
  const Row rows[] = {
      {"mj_step (all)", step},
      {"  forward", t[mjTIMER_FORWARD]},
      {"    position", t[mjTIMER_POSITION]},
      {"      kinematics", t[mjTIMER_POS_KINEMATICS]},
      {"      inertia", t[mjTIMER_POS_INERTIA]},
      {"      collision", t[mjTIMER_POS_COLLISION]},
      {"      make constraints", t[mjTIMER_POS_MAKE]},
      {"      project constraints", t[mjTIMER_POS_PROJECT]},
      {"    velocity", t[mjTIMER_VELOCITY]},
      {"    actuation", t[mjTIMER_ACTUATION]},
      {"    acceleration", t[mjTIMER_ACCELERATION]},
      {"    constraint (solver)", t[mjTIMER_CONSTRAINT]},
      {"  integration (step - forward)", step - t[mjTIMER_FORWARD]},
  };
  std::printf("  %-32s %12s %8s\n", "stage (MuJoCo timer)", "us/step", "share");
  for (const auto& r : rows) std::printf("  %-32s %12.3f %7.1f%%\n", r.name, r.us / p.steps, 100.0 * r.us / step);
}

}  // namespace

int main(int argc, char** argv) {
  double seconds = 2.0;
  int rounds = 3;
  std::string robot = "a1", mjcf;
  farm::cli::App app("bench_a1_step");
  app.description(
      "Where the time of a quadruped's physics step goes, for the shipped model and for the same model "
      "without its collision list; --mjcf profiles another quadruped's model file the same way.");
  app.add_option("--robot", robot, "The robot")
      ->check(CLI::IsMember({"a1", "honey_badger", "silver_badger"}))
      ->capture_default_str();
  app.add_option("--mjcf", mjcf, "An MJCF file to measure instead (needs a keyframe, a trunk body and actuators)");
  bench::add_seconds(app, seconds)->check(farm::cli::above(0, 600));
  app.add_option("--rounds", rounds, "Rounds per figure (the median is shown)")
      ->check(CLI::Range(1, 100))
      ->capture_default_str();
  if (const int rc = farm::cli::parse(app, argc, argv); rc >= 0) return rc;
  if (!mjcf.empty()) {
    char err[1000] = "";
    ModelPtr m(mj_loadXML(mjcf.c_str(), nullptr, err, sizeof err));
    if (!m) {
      std::fprintf(stderr, "bench_a1_step: %s: %s\n", mjcf.c_str(), err[0] ? err : "load failed");
      return 1;
    }
    if (m->nkey < 1 || m->nbody < 2 || m->nu < 1) {
      std::fprintf(stderr, "bench_a1_step: %s: needs a keyframe, a trunk body and actuators\n", mjcf.c_str());
      return 1;
    }
    std::printf("%s, one thread, %d rounds of %.1f s per figure (median); MuJoCo %d\n", mjcf.c_str(), rounds, seconds,
                mj_version());
    std::printf(
        "options: timestep %g, solver %d (0 PGS, 1 CG, 2 Newton), iterations %d, tolerance %g, cone %d "
        "(0 pyramidal, 1 elliptic), impratio %g, jacobian %d (0 dense, 1 sparse, 2 auto)\n",
        m->opt.timestep, m->opt.solver, m->opt.iterations, m->opt.tolerance, m->opt.cone, m->opt.impratio,
        m->opt.jacobian);
    Profile p;
    file_rate(m.get(), seconds, &p);
    print_profile(mjcf.c_str(), m.get(), p);
    std::vector<double> rates;
    for (int r = 0; r < rounds; ++r) rates.push_back(file_rate(m.get(), seconds, nullptr));
    std::printf("\nenv steps/s (one thread, 4 mj_step each, timers off): %.0f\n", median(rates));
    return 0;
  }
  farm::config::TaskConfig c;
  c.set_name(robot);
  auto base = farm::robots::make_task(c);
  const auto& task = static_cast<const QuadrupedTask&>(*base);
  const std::string path = "quadruped/" + robot + ".xml";
  ModelPtr shipped(farm::robots::load_embedded_model(path));
  ModelPtr before;
  try {
    before.reset(farm::robots::load_model_from_text(path, ts::without_collision_list(ts::embedded_text(path))));
  } catch (const std::exception& e) {
    std::fprintf(stderr, "bench_a1_step: %s: %s\n", path.c_str(), e.what());
    return 1;
  }
  std::printf("robot %s, one thread, %d rounds of %.1f s per figure (median); MuJoCo %d\n", robot.c_str(), rounds,
              seconds, mj_version());
  const Profile p_before = profile(task, before.get(), seconds);
  const Profile p_after = profile(task, shipped.get(), seconds);
  print_profile("without the collision list (before)", before.get(), p_before);
  print_profile("shipped (after)", shipped.get(), p_after);

  // The solver: looser tolerances and the other solvers against the shipped Newton settings.
  const int kSolverSteps = 4000;
  const SolverRun ref = solver_run(task, shipped.get(), shipped->opt.solver, shipped->opt.tolerance, kSolverSteps);
  std::printf("\nsolver settings on the shipped model, %d env steps of one seeded rollout (one round each):\n",
              kSolverSteps);
  std::printf("  %-28s %14s %14s %28s\n", "settings", "iters/step", "env steps/s", "max |qpos - shipped's|");
  struct Variant {
    const char* name;
    int solver;
    double tolerance;
  };
  const Variant variants[] = {{"shipped (Newton, 1e-8)", shipped->opt.solver, shipped->opt.tolerance},
                              {"Newton, tolerance 1e-6", mjSOL_NEWTON, 1e-6},
                              {"Newton, tolerance 1e-5", mjSOL_NEWTON, 1e-5},
                              {"CG, tolerance 1e-8", mjSOL_CG, 1e-8},
                              {"PGS, tolerance 1e-8", mjSOL_PGS, 1e-8}};
  for (const auto& v : variants) {
    const SolverRun r = solver_run(task, shipped.get(), v.solver, v.tolerance, kSolverSteps);
    double worst = 0;
    for (size_t i = 0; i < r.qpos.size(); ++i) worst = std::max(worst, std::abs(r.qpos[i] - ref.qpos[i]));
    std::printf("  %-28s %14.3f %14.0f %28.3g\n", v.name, r.iters_per_step, r.rate, worst);
  }

  std::vector<double> raw_b, raw_a, env_b, env_a;
  for (int r = 0; r < rounds; ++r) {  // interleaved, so a busy moment hits both
    raw_b.push_back(raw_rate(task, before.get(), seconds));
    raw_a.push_back(raw_rate(task, shipped.get(), seconds));
    env_b.push_back(task_rate(task, before.get(), seconds));
    env_a.push_back(task_rate(task, shipped.get(), seconds));
  }
  std::printf("\n%-28s %18s %18s %8s\n", "env steps/s (one thread)", "before", "after", "change");
  std::printf("%-28s %18.0f %18.0f %+7.1f%%\n", "raw mj_step x4", median(raw_b), median(raw_a),
              100.0 * (median(raw_a) / median(raw_b) - 1));
  std::printf("%-28s %18.0f %18.0f %+7.1f%%\n", "task (random actions)", median(env_b), median(env_a),
              100.0 * (median(env_a) / median(env_b) - 1));
  return 0;
}
