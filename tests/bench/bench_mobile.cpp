// Mobile-robot env throughput on one core against the physics alone: env steps/s of the Jetbot
// and Kaya goal-reaching tasks (lidar on, obstacle maps, resets, reward) next to a raw mj_step
// loop of the same model, counted in env-step equivalents (control_substeps physics steps).
// Usage: bench_mobile [--seconds S] [--rays N] [--dt DT --substeps K]
#include <mujoco/mujoco.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "bench_options.h"
#include "mobile/mobile_task.h"
#include "task.h"

namespace {

using Clock = std::chrono::steady_clock;
using farm::robots::mobile::MobileTask;

double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

// Physics steps/s of the task's model driving straight on its first map, reset to the start
// every 200 steps so it stays on the floor inside the arena.
double raw_physics_steps_per_second(const MobileTask& task, double seconds) {
  auto s = task.make_state();
  std::vector<float> obs(task.spec().obs_dim);
  task.reset(*s, 1, obs.data());
  mjData* d = s->data;
  mjData* start = mj_copyData(nullptr, task.model(), d);
  const auto w = task.wheel_speeds({0.1, 0, 0});
  uint64_t steps = 0;
  const auto t0 = Clock::now();
  double elapsed = 0;
  do {
    mj_copyData(d, task.model(), start);
    for (int i = 0; i < task.num_wheels(); ++i) d->ctrl[i] = w[i];
    for (int i = 0; i < 200; ++i) mj_step(task.model(), d);
    steps += 200;
    elapsed = seconds_since(t0);
  } while (elapsed < seconds);
  mj_deleteData(start);
  return steps / elapsed;
}

// Env steps/s with uniformly random discrete actions, episodes reset as they end.
double env_steps_per_second(const MobileTask& task, double seconds, uint64_t* episodes) {
  auto s = task.make_state();
  std::vector<float> obs(task.spec().obs_dim);
  std::mt19937_64 rng(1);
  std::uniform_int_distribution<int> pick(0, task.spec().num_actions - 1);
  uint64_t seed = 1, steps = 0;
  *episodes = 0;
  task.reset(*s, seed++, obs.data());
  const auto t0 = Clock::now();
  double elapsed = 0;
  do {
    for (int i = 0; i < 100; ++i) {
      const float a = float(pick(rng));
      const auto r = task.step(*s, &a, obs.data());
      if (r.terminated || r.truncated) {
        task.reset(*s, seed++, obs.data());
        ++*episodes;
      }
    }
    steps += 100;
    elapsed = seconds_since(t0);
  } while (elapsed < seconds);
  return steps / elapsed;
}

}  // namespace

int main(int argc, char** argv) {
  double seconds = 3.0;
  int rays = 12, substeps = 0;
  double dt = 0;
  farm::cli::App app("bench_mobile");
  app.description(
      "Mobile-robot env throughput on one core against the physics alone: env steps/s of the Jetbot "
      "and Kaya goal-reaching tasks next to a raw mj_step loop of the same model.");
  bench::add_seconds(app, seconds);
  app.add_option("--rays", rays, "Lidar rays")->capture_default_str();
  app.add_option("--dt", dt, "Physics timestep (with --substeps; default: the task's)");
  app.add_option("--substeps", substeps, "Physics steps per control step (with --dt; default: the task's)");
  if (const int rc = farm::cli::parse(app, argc, argv); rc >= 0) return rc;
  std::printf("one core; lidar %d rays; figures are per core; physics dt %s\n", rays,
              dt > 0 ? std::to_string(dt).c_str() : "default");
  std::printf("%-7s %8s %14s %16s %14s %7s %9s\n", "robot", "substeps", "raw mj_step/s", "raw env-equiv/s",
              "env steps/s", "ratio", "episodes");
  for (const char* name : {"jetbot", "kaya"}) {
    farm::config::TaskConfig c;
    c.set_name(name);
    auto* scene =
        std::string(name) == "jetbot" ? c.mutable_jetbot()->mutable_scene() : c.mutable_kaya()->mutable_scene();
    scene->set_lidar_rays(rays);
    scene->set_max_episode_steps(400);
    if (dt > 0) scene->set_physics_dt(dt);
    if (substeps > 0) scene->set_control_substeps(substeps);
    auto base = farm::robots::make_task(c);
    const auto& task = static_cast<const MobileTask&>(*base);
    const int sub = scene->control_substeps();
    const double raw = raw_physics_steps_per_second(task, seconds);
    uint64_t episodes = 0;
    const double env = env_steps_per_second(task, seconds, &episodes);
    const double limit = raw / sub;  // env steps/s if an env step cost only its physics
    std::printf("%-7s %8d %14.0f %16.0f %14.0f %6.1f%% %9llu\n", name, sub, raw, limit, env, 100.0 * env / limit,
                (unsigned long long)episodes);
  }
  return 0;
}
