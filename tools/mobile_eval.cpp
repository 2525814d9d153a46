// farm-mobile-eval: evaluates a trained Jetbot or Kaya policy from a run's checkpoint on fresh
// random obstacle maps (success rate, episode time, path length) and draws sample trajectories
// over their maps as a PNG.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <iostream>
#include <string>
#include <vector>

#include "cli.h"
#include "mlp.h"
#include "mobile/mobile_task.h"
#include "png_canvas.h"
#include "run_policy.h"
#include "task.h"

using namespace farm;
using farm::robots::mobile::MobileState;
using farm::robots::mobile::MobileTask;

namespace {

struct Options {
  std::string run_dir, plot, checkpoint = "checkpoint";
  int episodes = 100, plot_episodes = 6;
  uint64_t seed = 20261123;
  bool failures = false;
};

// Declares the options into o; --run-dir is required.
void add_options(CLI::App& app, Options& o) {
  app.description(
      "Runs N episodes of the deterministic policy in DIR/checkpoint (with --best: in DIR/best, the\n"
      "networks of the learner's best evaluation) on fresh random maps drawn from seed S, prints success\n"
      "rate, mean episode time and path length, and with --plot draws the first K episodes over their maps.");
  app.add_option("--run-dir", o.run_dir, "The run folder")->required();
  app.add_flag_callback(
      "--best", [&o] { o.checkpoint = "best"; }, "DIR/best, the networks of the learner's best evaluation");
  app.add_option("--episodes", o.episodes, "Episodes to run")->check(CLI::Range(1, 1000000))->capture_default_str();
  app.add_option("--seed", o.seed, "Seed of the random maps")->check(farm::cli::whole_number())->capture_default_str();
  app.add_option("--plot", o.plot, "Draw the first K episodes over their maps (FILE.png)");
  app.add_option("--plot-episodes", o.plot_episodes, "K: episodes drawn with --plot")
      ->check(CLI::Range(1, 100))  // a 320-pixel panel each, three to a row
      ->capture_default_str();
  app.add_flag("--failures", o.failures,
               "List every episode that did not reach the goal: where it ended, the shortest lidar range then, "
               "and for a collision what the robot touched");
}

struct Episode {
  MobileState* state = nullptr;
  bool success = false, collision = false;
  double time = 0, path = 0, ret = 0;
};

void draw_panel(tools::Canvas& c, int ox, int oy, int size, const MobileTask& task, const MobileState& s,
                bool success) {
  const double h = task.scene().arena_half_size();
  const double scale = (size - 20) / (2 * h);
  auto px = [&](double x) { return ox + 10 + (x + h) * scale; };
  auto py = [&](double y) { return oy + 10 + (h - y) * scale; };
  c.fill_rect(ox + 10, oy + 10, ox + size - 10, oy + size - 10, {250, 250, 245});
  // Walls.
  const tools::Rgb wall{90, 70, 50};
  c.fill_rect(px(-h) - 3, py(h) - 3, px(h) + 3, py(h), wall);
  c.fill_rect(px(-h) - 3, py(-h), px(h) + 3, py(-h) + 3, wall);
  c.fill_rect(px(-h) - 3, py(h) - 3, px(-h), py(-h) + 3, wall);
  c.fill_rect(px(h), py(h) - 3, px(h) + 3, py(-h) + 3, wall);
  const tools::Rgb obstacle{180, 80, 60};
  for (const auto& o : s.map.obstacles) {
    const auto& slot = task.maps().slots()[o.slot];
    if (!slot.box) {
      c.fill_circle(px(o.x), py(o.y), slot.half_size * scale, obstacle);
      continue;
    }
    std::vector<double> xs, ys;
    const double cs = std::cos(o.yaw), sn = std::sin(o.yaw), a = slot.half_size;
    const double corners[4][2] = {{a, a}, {-a, a}, {-a, -a}, {a, -a}};
    for (const auto& k : corners) {
      xs.push_back(px(o.x + cs * k[0] - sn * k[1]));
      ys.push_back(py(o.y + sn * k[0] + cs * k[1]));
    }
    c.fill_polygon(xs, ys, obstacle);
  }
  // Goal region, path, start.
  c.fill_circle(px(s.map.goal_x), py(s.map.goal_y), std::max(4.0, task.scene().goal_radius() * scale), {220, 40, 40});
  const tools::Rgb path = success ? tools::Rgb{30, 90, 200} : tools::Rgb{120, 120, 120};
  for (size_t i = 2; i + 1 < s.trajectory.size(); i += 2) {
    c.line(px(s.trajectory[i - 2]), py(s.trajectory[i - 1]), px(s.trajectory[i]), py(s.trajectory[i + 1]), 2.5, path);
  }
  c.fill_circle(px(s.map.start_x), py(s.map.start_y), task.robot_radius() * scale, {40, 160, 60});
}

// One line per failed episode: outcome, time, end pose and distance to the goal, the shortest lidar
// range after the last step, and for a collision the bodies in contact with the robot.
void describe_failure(const MobileTask& task, const MobileState& s, int episode, bool collision) {
  double x, y, yaw;
  task.pose(s, &x, &y, &yaw);
  double nearest = task.scene().lidar_range();
  for (double r : s.scan) nearest = std::min(nearest, r);
  const mjModel* m = task.model();
  const int base = mj_name2id(m, mjOBJ_BODY, "base");
  const double z = base >= 0 ? s.data->xpos[3 * base + 2] : NAN;
  std::string touched;
  if (collision) {
    for (int i = 0; i < s.data->ncon; ++i) {
      for (int g : {s.data->contact[i].geom1, s.data->contact[i].geom2}) {
        if (m->geom_group[g] != 1) continue;  // walls and obstacles
        const char* geom = mj_id2name(m, mjOBJ_GEOM, g);
        const char* body = mj_id2name(m, mjOBJ_BODY, m->geom_bodyid[g]);
        const std::string name = geom ? geom : body ? body : "?";
        if (touched.find(name) == std::string::npos) touched += (touched.empty() ? "" : ", ") + name;
      }
    }
  }
  std::printf(
      "episode %3d: %-9s at %5.1f s, (%+.2f, %+.2f) heading %+.0f deg, base at %.3f m, %.2f m "
      "from the goal, shortest lidar range %.2f m%s%s\n",
      episode, collision ? "collision" : "time-out", s.step * task.control_dt(), x, y, yaw * 180 / M_PI, z,
      s.last_distance, nearest, touched.empty() ? "" : ", touching ", touched.c_str());
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  farm::cli::App app("farm-mobile-eval");
  add_options(app, o);
  // Every refusal of farm-mobile-eval, bad usage included, exits 1.
  if (const int rc = farm::cli::parse(app, argc, argv, 1); rc >= 0) return rc;
  try {
    const tools::RunPolicy rp = tools::load_run_policy(tools::run_policy_dir(o.run_dir, o.checkpoint == "best"));
    const config::CheckpointManifest& m = rp.manifest;
    const config::ExperimentConfig& cfg = rp.config;
    auto* task = dynamic_cast<MobileTask*>(rp.task.get());
    if (!task) throw std::runtime_error("task '" + cfg.task().name() + "' is not a mobile robot");
    Policy policy(rp.policy);

    std::vector<std::unique_ptr<robots::TaskState>> states;
    std::vector<Episode> eps(o.episodes);
    std::vector<float> obs(task->spec().obs_dim), act(task->spec().act_dim);
    std::mt19937_64 rng(o.seed);
    for (int i = 0; i < o.episodes; ++i) {
      states.push_back(task->make_state());
      auto& s = static_cast<MobileState&>(*states.back());
      s.record_trajectory = i < o.plot_episodes;
      task->reset(s, rng(), obs.data());
      for (;;) {
        policy.act(obs.data(), 1, rng, true, act.data(), nullptr);
        const auto r = task->step(s, act.data(), obs.data());
        if (r.terminated || r.truncated) break;
      }
      std::vector<float> metrics(task->spec().metric_names.size());
      task->episode_metrics(s, metrics.data());
      eps[i] = {&s, metrics[0] > 0.5f, metrics[3] > 0.5f, metrics[1], metrics[2], s.episode_return};
      if (o.failures && !eps[i].success) describe_failure(*task, s, i, eps[i].collision);
      if (!s.record_trajectory) states.back().reset();
    }
    int ok = 0, crashed = 0;
    double time = 0, path = 0;
    for (const auto& e : eps) {
      if (e.success) {
        ++ok;
        time += e.time;
        path += e.path;
      }
      crashed += e.collision;
    }
    std::printf("%s: policy v%llu (%lld updates, %llu env steps) on %d fresh maps (seed %llu)\n",
                cfg.experiment_id().c_str(), (unsigned long long)m.policy_version(), (long long)m.updates(),
                (unsigned long long)m.env_steps(), o.episodes, (unsigned long long)o.seed);
    std::printf("success rate      %.1f %% (%d of %d)\n", 100.0 * ok / o.episodes, ok, o.episodes);
    std::printf("collisions        %d, time-outs %d\n", crashed, o.episodes - ok - crashed);
    if (ok > 0) {
      std::printf("episode time      %.1f s (mean over successes; control step %.3f s)\n", time / ok,
                  task->control_dt());
      std::printf("path length       %.1f cm (mean over successes)\n", 100.0 * path / ok);
    }
    if (!o.plot.empty()) {
      const int k = std::min(o.plot_episodes, o.episodes), cols = std::min(k, 3);
      const int rows = (k + cols - 1) / cols, size = 320;
      tools::Canvas c(cols * size, rows * size, {255, 255, 255});
      for (int i = 0; i < k; ++i)
        draw_panel(c, (i % cols) * size, (i / cols) * size, size, *task, *eps[i].state, eps[i].success);
      c.write_png(o.plot);
      std::printf(
          "trajectories      %s (%d episodes: start green, goal red, path blue when "
          "it reached the goal, grey when not; obstacles brown)\n",
          o.plot.c_str(), k);
    }
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "farm-mobile-eval: %s\n", e.what());
    return 1;
  }
}
