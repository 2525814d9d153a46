// Characterization sweep of the mCLARI microbot (mCLARI thesis §5.1-5.2): every phase group x a list of
// frequencies on each terrain, each run as one fixed-action episode, spread over threads.
// Writes <out>/trajectories.csv (centre of mass after every 1 s step), <out>/summary.csv (mean
// power, speed and efficiency per terrain, group and frequency), <out>/best.csv (the best fixed
// (group, f) per terrain by efficiency) and <out>/height_field.png; tools/mclari_plots.py draws
// the 27-panel trajectory grid and efficiency against frequency from them.
#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <mutex>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <tuple>
#include <vector>

#include "cli.h"
#include "config.h"
#include "mclari/mclari_task.h"
#include "mclari/phase_groups.h"
#include "mclari/terrain.h"
#include "task_specs.h"

using farm::robots::McLariState;
using farm::robots::McLariTask;
namespace mclari = farm::robots::mclari;

namespace {

std::vector<int> int_list(const std::string& s, const char* flag) {
  std::vector<int> v;
  std::stringstream in(s);
  std::string item;
  while (std::getline(in, item, ',')) {
    try {
      size_t used = 0;
      v.push_back(std::stoi(item, &used));
      if (used != item.size()) throw std::invalid_argument(item);
    } catch (const std::exception&) {
      throw std::invalid_argument(std::string(flag) + ": '" + item + "' is not an integer");
    }
  }
  if (v.empty()) throw std::invalid_argument(std::string(flag) + ": empty list");
  return v;
}

struct Job {
  int terrain, group, frequency;
};

struct Result {
  Job job;
  std::vector<std::array<double, 2>> path;      // com x, y after each step (mm), path[0] = start
  double power = 0, speed = 0, efficiency = 0;  // means over the steps before a fall
  int steps = 0;
  bool fell = false;
  double wall_s = 0;
};

}  // namespace

int main(int argc, char** argv) {
  std::string out, config_path;
  int seconds = 60, threads = int(std::max(1u, std::thread::hardware_concurrency())), spp = 0;
  uint64_t seed = 1;
  std::vector<int> freqs = {1, 20, 40, 60, 80, 100, 120, 150};  // mCLARI thesis §5.1
  std::vector<int> groups, terrains = {0, 1, 2, 3, 4, 5};
  std::string groups_arg = "all";
  farm::cli::App app("farm-mclari-sweep");
  app.description("Runs every phase group x frequency on each terrain as one fixed-action episode.");
  app.add_option("--out", out, "Folder of the CSV files and the height field")->required();
  app.add_option("--config", config_path, "Take task.mclari from this experiment config (defaults: mCLARI thesis)");
  app.add_option("--seconds", seconds, "Episode length in 1 s steps (mCLARI thesis §5.1: 1 minute)")
      ->check(CLI::Range(1, INT32_MAX))
      ->capture_default_str();
  app.add_option("--frequencies", freqs, "Comma-separated frequencies in Hz")->delimiter(',')->capture_default_str();
  app.add_option("--groups", groups_arg, "all, reduced or comma-separated phase groups G,G,...")->capture_default_str();
  app.add_option("--terrains", terrains, "Comma-separated terrains")
      ->delimiter(',')
      ->check(CLI::Range(0, mclari::kNumTerrains - 1))
      ->capture_default_str();
  app.add_option("--steps-per-period", spp, "Override task.mclari.steps_per_period (timestep 1 / (N f))");
  app.add_option("--threads", threads, "Threads")->check(CLI::Range(1, INT32_MAX))->capture_default_str();
  app.add_option("--seed", seed, "Seed")->check(farm::cli::whole_number())->capture_default_str();
  if (const int rc = farm::cli::parse(app, argc, argv); rc >= 0) return rc;
  try {
    if (groups_arg == "all") {
      for (int g = 0; g < mclari::kNumGroups; ++g) groups.push_back(g);
    } else if (groups_arg == "reduced") {
      groups = mclari::reduced_groups();
    } else {
      groups = int_list(groups_arg, "--groups");
    }
    for (int g : groups)
      if (g < 0 || g >= mclari::kNumGroups)
        throw std::invalid_argument("--groups: " + std::to_string(g) + " not in [0, 27)");

    farm::config::MclariConfig base;
    if (!config_path.empty()) base = farm::robots::load_config_file(config_path).task().mclari();
    if (spp > 0) base.set_steps_per_period(spp);
    for (int f : freqs)
      if (f < base.min_frequency() || f > base.max_frequency())
        throw std::invalid_argument("--frequencies: " + std::to_string(f) + " Hz outside the task's range");
    // A fixed action for the whole run; the target is put out of reach so the run lasts.
    base.set_max_episode_steps(seconds);
    base.set_target_min_distance(base.ground_half_size() * 0.8);
    base.set_target_max_distance(base.ground_half_size() * 0.8);
    base.set_target_radius(1e-3);
    std::filesystem::create_directories(out);
    base.set_hfield_png(out + "/height_field.png");

    std::vector<Job> jobs;
    for (int t : terrains)
      for (int g : groups)
        for (int f : freqs) jobs.push_back({t, g, f});
    // Longest first (cost grows with f), so the pool ends together.
    std::stable_sort(jobs.begin(), jobs.end(), [](const Job& a, const Job& b) { return a.frequency > b.frequency; });
    std::vector<Result> results(jobs.size());
    std::atomic<size_t> next{0};
    std::mutex log_mu;
    size_t done = 0;
    const auto t0 = std::chrono::steady_clock::now();

    // One task per fixed (f, group); the model and height field are shared by its episodes.
    auto worker = [&]() {
      for (size_t i = next++; i < jobs.size(); i = next++) {
        const Job& j = jobs[i];
        const auto w0 = std::chrono::steady_clock::now();
        farm::config::MclariConfig cfg = base;
        cfg.set_fixed_frequency(j.frequency);
        cfg.set_fixed_group(j.group);
        if (i != 0) cfg.clear_hfield_png();
        McLariTask task(cfg);
        auto s = task.make_state();
        auto& ms = static_cast<McLariState&>(*s);
        std::vector<float> obs(size_t(task.spec().obs_dim));  // 4 to 9 by the config's observe_*
        float act[2] = {0.f, 0.f};
        task.reset_on(*s, seed, j.terrain, obs.data());
        Result& r = results[i];
        r.job = j;
        auto c = McLariTask::com(*s);
        r.path.push_back({c[0], c[1]});
        for (int k = 0; k < seconds; ++k) {
          const auto step = task.step(*s, act, obs.data());
          if (ms.fell) {
            r.fell = true;
            break;
          }
          c = McLariTask::com(*s);
          r.path.push_back({c[0], c[1]});
          r.power += ms.last.power;
          r.speed += ms.last.speed_mm_s;
          r.efficiency += ms.last.efficiency;
          r.steps += 1;
          if (step.terminated || step.truncated) break;
        }
        if (r.steps > 0) {
          r.power /= r.steps;
          r.speed /= r.steps;
          r.efficiency /= r.steps;
        }
        r.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - w0).count();
        std::lock_guard<std::mutex> lock(log_mu);
        ++done;
        if (done % 25 == 0 || done == jobs.size()) {
          const double el = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
          std::fprintf(stderr, "sweep: %zu / %zu runs, %.0f s\n", done, jobs.size(), el);
        }
      }
    };
    std::vector<std::thread> pool;
    for (int k = 1; k < threads; ++k) pool.emplace_back(worker);
    worker();
    for (auto& th : pool) th.join();

    std::sort(results.begin(), results.end(), [](const Result& a, const Result& b) {
      return std::tie(a.job.terrain, a.job.group, a.job.frequency) <
             std::tie(b.job.terrain, b.job.group, b.job.frequency);
    });
    std::ofstream traj(out + "/trajectories.csv"), sum(out + "/summary.csv"), best(out + "/best.csv");
    if (!traj || !sum || !best) throw std::runtime_error("cannot write CSV files under " + out);
    traj << "terrain,terrain_name,group,frequency_hz,t_s,x_mm,y_mm\n";
    sum << "terrain,terrain_name,group,group_name,frequency_hz,power_w,speed_mm_s,efficiency,steps,fell,wall_s\n";
    // seconds: how long each fixed point ran, so an evaluation can tell whether its episodes match.
    best << "terrain,terrain_name,group,group_name,frequency_hz,efficiency,speed_mm_s,power_w,seconds\n";
    char line[512];
    for (const auto& r : results) {
      for (size_t k = 0; k < r.path.size(); ++k) {
        std::snprintf(line, sizeof line, "%d,%s,%d,%d,%zu,%.4f,%.4f\n", r.job.terrain,
                      mclari::terrain_name(r.job.terrain), r.job.group, r.job.frequency, k, r.path[k][0], r.path[k][1]);
        traj << line;
      }
      std::snprintf(line, sizeof line, "%d,%s,%d,\"%s\",%d,%.6e,%.5f,%.6f,%d,%d,%.2f\n", r.job.terrain,
                    mclari::terrain_name(r.job.terrain), r.job.group, mclari::group_name(r.job.group).c_str(),
                    r.job.frequency, r.power, r.speed, r.efficiency, r.steps, int(r.fell), r.wall_s);
      sum << line;
    }
    std::printf("%-13s %-18s %6s %10s %10s %12s\n", "terrain", "best group", "f [Hz]", "efficiency", "v [mm/s]",
                "P [W]");
    for (int t : terrains) {
      const Result* b = nullptr;
      for (const auto& r : results)
        if (r.job.terrain == t && !r.fell && (!b || r.efficiency > b->efficiency)) b = &r;
      if (!b) continue;
      std::snprintf(line, sizeof line, "%d,%s,%d,\"%s\",%d,%.6f,%.5f,%.6e,%g\n", t, mclari::terrain_name(t),
                    b->job.group, mclari::group_name(b->job.group).c_str(), b->job.frequency, b->efficiency, b->speed,
                    b->power, seconds * base.step_seconds());
      best << line;
      std::printf("%-13s %-18s %6d %10.4f %10.3f %12.3e\n", mclari::terrain_name(t),
                  mclari::group_name(b->job.group).c_str(), b->job.frequency, b->efficiency, b->speed, b->power);
    }
    const double el = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    std::printf("%zu runs of %d s on %d threads in %.0f s; CSV under %s\n", results.size(), seconds, threads, el,
                out.c_str());
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "farm-mclari-sweep: %s\n", e.what());
    return 2;
  }
}
