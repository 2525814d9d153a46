// mCLARI simulation throughput: RL steps per second of one worker thread at f = 1, 20 and 150 Hz
// (one RL step = 1 s simulated at a timestep of 1 / (500 f), mCLARI thesis §5.3), against a raw mj_step
// loop of the same model at the same timestep, the limit of the task's own work per step.
// The mCLARI thesis §5.3: 5,000 steps at 150 Hz took 5 hours (0.28 steps/s).
#include <mujoco/mujoco.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>

#include "cli.h"
#include "mclari/mclari_task.h"
#include "mclari/terrain.h"

using farm::robots::McLariState;
using farm::robots::McLariTask;

namespace {

double now() { return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count(); }

}  // namespace

int main(int argc, char** argv) {
  double min_seconds = 3.0;
  int terrain = 0;
  farm::cli::App app("bench_mclari");
  app.description("mCLARI RL steps per second of one thread at 1, 20 and 150 Hz, against a raw mj_step loop.");
  app.add_option("seconds", min_seconds, "SECONDS: the least time measured per figure")
      ->check(farm::cli::positive())
      ->capture_default_str();
  app.add_option("terrain", terrain, "TERRAIN: the terrain the robot walks on")
      ->check(CLI::Range(0, farm::robots::mclari::kNumTerrains - 1))
      ->capture_default_str();
  if (const int rc = farm::cli::parse(app, argc, argv); rc >= 0) return rc;
  std::printf("mCLARI, terrain %d, one thread; steps per period 500 (mCLARI thesis)\n", terrain);
  std::printf("%6s %14s %16s %16s %8s %22s\n", "f [Hz]", "RL steps/s", "mj_step/s (task)", "mj_step/s (raw)", "ratio",
              "mCLARI thesis at 150 Hz");
  for (int f : {1, 20, 150}) {
    farm::config::MclariConfig cfg;
    cfg.set_fixed_frequency(f);
    cfg.set_fixed_group(19);
    McLariTask task(cfg);
    auto s = task.make_state();
    float obs[4], act[2] = {0, 0};
    task.reset_on(*s, 1, terrain, obs);
    task.step(*s, act, obs);  // warm-up
    int steps = 0;
    const double t0 = now();
    while (now() - t0 < min_seconds || steps < 2) {
      const auto r = task.step(*s, act, obs);
      ++steps;
      if (r.terminated || r.truncated) task.reset_on(*s, steps, terrain, obs);
    }
    const double rl_per_s = steps / (now() - t0);
    const int per_step = static_cast<McLariState&>(*s).last.physics_steps;

    // Raw loop: the same model and timestep, the same state, only mj_step.
    mjModel* m = static_cast<McLariState&>(*s).model;
    mjData* d = mj_makeData(m);
    mj_copyData(d, m, s->data);
    long raw = 0;
    const double t1 = now();
    while (now() - t1 < min_seconds || raw < per_step) {
      for (int k = 0; k < 1000; ++k) mj_step(m, d);
      raw += 1000;
    }
    const double raw_per_s = raw / (now() - t1);
    mj_deleteData(d);
    const double task_mj = rl_per_s * per_step;
    std::printf("%6d %14.3f %16.0f %16.0f %8.3f %22s\n", f, rl_per_s, task_mj, raw_per_s, task_mj / raw_per_s,
                f == 150 ? "0.278 steps/s" : "");
  }
  std::printf("ratio = the task's physics steps per second / the raw mj_step loop's (1.0 = no overhead)\n");
  return 0;
}
