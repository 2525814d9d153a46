// Quadruped env throughput on one core against the physics alone: env steps/s of the A1, Honey
// Badger and Silver Badger walking tasks (PD control on every physics step, observation with
// noise, reward terms, contacts, randomized resets) next to a raw mj_step loop of the same model
// holding its default pose, counted in env-step equivalents (decimation physics steps).
// Usage: bench_quadruped [--seconds S]
#include <mujoco/mujoco.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <random>
#include <vector>

#include "bench_options.h"
#include "quadruped/quadruped_task.h"
#include "quadruped_rate.h"
#include "task.h"

namespace {

using Clock = std::chrono::steady_clock;
using farm::robots::quadruped::QuadrupedState;
using farm::robots::quadruped::QuadrupedTask;

double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

// Physics steps/s of the model under the simplest PD hold of the start pose, restarted every
// 1,000 steps.
double raw_physics_steps_per_second(const QuadrupedTask& task, double seconds) {
  auto s = task.make_state();
  std::vector<float> obs(task.spec().obs_dim);
  task.reset(*s, 1, obs.data());
  const mjModel* m = static_cast<QuadrupedState&>(*s).model;
  mjData* d = s->data;
  mjData* start = mj_copyData(nullptr, m, d);
  const auto& c = task.config();
  uint64_t steps = 0;
  const auto t0 = Clock::now();
  double elapsed = 0;
  do {
    mj_copyData(d, m, start);
    for (int i = 0; i < 1000; ++i) {
      for (int a = 0; a < m->nu; ++a) {
        const int j = m->actuator_trnid[2 * a];
        d->ctrl[a] =
            c.kp() * (start->qpos[m->jnt_qposadr[j]] - d->qpos[m->jnt_qposadr[j]]) - c.kd() * d->qvel[m->jnt_dofadr[j]];
      }
      mj_step(m, d);
    }
    steps += 1000;
    elapsed = seconds_since(t0);
  } while (elapsed < seconds);
  mj_deleteData(start);
  return steps / elapsed;
}

// Env steps/s with uniformly random actions in [-0.5, 0.5], episodes reset as they end.
double env_steps_per_second(const QuadrupedTask& task, double seconds, uint64_t* episodes) {
  auto s = task.make_state();
  return farm::bench::random_action_rate(task, *s, seconds, episodes);
}

}  // namespace

int main(int argc, char** argv) {
  double seconds = 3.0;
  farm::cli::App app("bench_quadruped");
  app.description("Raw physics and env steps per second of each quadruped, one core.");
  bench::add_seconds(app, seconds);
  if (const int rc = farm::cli::parse(app, argc, argv); rc >= 0) return rc;
  std::printf("one core; figures are per core\n");
  std::printf("%-14s %10s %14s %16s %14s %7s %9s\n", "robot", "decimation", "raw mj_step/s", "raw env-equiv/s",
              "env steps/s", "ratio", "episodes");
  for (const char* name : {"a1", "honey_badger", "silver_badger"}) {
    farm::config::TaskConfig c;
    c.set_name(name);
    auto base = farm::robots::make_task(c);
    const auto& task = static_cast<const QuadrupedTask&>(*base);
    const int dec = task.config().decimation();
    const double raw = raw_physics_steps_per_second(task, seconds);
    uint64_t episodes = 0;
    const double env = env_steps_per_second(task, seconds, &episodes);
    const double limit = raw / dec;
    std::printf("%-14s %10d %14.0f %16.0f %14.0f %6.1f%% %9llu\n", name, dec, raw, limit, env, 100.0 * env / limit,
                (unsigned long long)episodes);
  }
  return 0;
}
