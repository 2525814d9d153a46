// farm-play: renders a trained run's deterministic policy, as the workers run it, on its task to a
// video (MP4, an animated GIF or PNG frames) without a GPU or a display: MuJoCo's renderer on
// OSMesa, frames piped to ffmpeg at the video's rate (not once per physics or control step), a
// camera that follows the robot, the episode's return and the task's metrics drawn on the frame
// and printed per episode.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <iostream>
#include <memory>
#include <random>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "config_policy.h"
#include "mlp.h"
#include "offscreen_renderer.h"
#include "play_view.h"
#include "vec_env.h"
#include "video_writer.h"

using namespace farm;

namespace {

const char* kUsage =
    "usage: farm-play (--run RUN [--best] | --checkpoint DIR | --config EXPERIMENT.txtpb)\n"
    "                 [--config EXPERIMENT.txtpb --checkpoint DIR]\n"
    "                 --out FILE.mp4|FILE.gif|FOLDER/\n"
    "                 [--episodes 1] [--seed 1] [--width 640] [--height 480] [--fps 25] [--max-steps N]\n"
    "                 [--max-seconds S]\n"
    "                 [--distance D] [--azimuth 90] [--elevation DEG] [--no-overlay] [--view-check]\n"
    "                 [--ffmpeg ffmpeg]\n"
    "Plays the deterministic policy of RUN/checkpoint (--best: RUN/best, the learner's best\n"
    "evaluation; --checkpoint: any such folder) for N episodes of its task and writes them to one\n"
    "video: .mp4 (H.264), .gif (looping) or numbered PNG frames in a folder. Episode i starts from\n"
    "the reset seed the worker's evaluation of N episodes from seed S gives its env i.\n"
    "  --config       the experiment from this file, not from the checkpoint's manifest: with\n"
    "                 --checkpoint, for a policy folder without one (docs/data/mclari_terrain_policy);\n"
    "                 alone, the experiment's untrained policy (its learner's initial networks), to\n"
    "                 look at a task and the camera before training\n"
    "  --fps          frames per second of simulated time (the video plays in real time)\n"
    "  --max-steps    end each episode after this many control steps (default: the task's limit)\n"
    "  --max-seconds  end each episode once this much time is simulated\n"
    "  --distance, --azimuth, --elevation   the camera that follows the robot (default: from the\n"
    "                 robot's size; azimuth 90 looks along +y; elevation in degrees, negative: from above)\n"
    "  --no-overlay   no text on the frames (return, step, time, the task's metrics)\n"
    "  --view-check   also measure the share of each frame the robot covers; exit 3 when it leaves\n"
    "                 the picture (covers fewer than 20 pixels)\n"
    "  --ffmpeg       the ffmpeg program (default: ffmpeg on PATH)\n";

// The pixels of a frame's scene below which --view-check says the robot is out of the picture.
constexpr int64_t kMinRobotPixels = 20;
// Rows of each overlay column (the first holds the episode, the step and time, and the return).
constexpr int kOverlayRows = 4;
// Frame times are compared with this slack (in frames), so a clock of summed physics steps that
// lands a rounding error short of a frame's time still shows that frame.
constexpr double kFrameSlack = 1e-3;

struct Options {
  std::string run, checkpoint, config, out, ffmpeg = "ffmpeg";
  bool best = false, overlay = true, view_check = false;
  int episodes = 1, width = 640, height = 480, fps = 25, max_steps = 0;
  double max_seconds = 0;
  uint64_t seed = 1;
  tools::CameraChoice camera;
};

std::string fmt(const char* f, double v) {
  char text[64];
  std::snprintf(text, sizeof text, f, v);
  return text;
}

long long parse_integer(const std::string& flag, const std::string& text, long long lo, long long hi) {
  size_t used = 0;
  long long v = 0;
  try {
    v = std::stoll(text, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used == 0 || used != text.size()) throw std::invalid_argument(flag + ": expected an integer, got '" + text + "'");
  if (v < lo || v > hi)
    throw std::invalid_argument(flag + ": " + text + " is outside [" + std::to_string(lo) + ", " + std::to_string(hi) +
                                "]");
  return v;
}

double parse_number(const std::string& flag, const std::string& text, double lo, double hi) {
  size_t used = 0;
  double v = 0;
  try {
    v = std::stod(text, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used == 0 || used != text.size() || !std::isfinite(v))
    throw std::invalid_argument(flag + ": expected a number, got '" + text + "'");
  if (v < lo || v > hi)
    throw std::invalid_argument(flag + ": " + text + " is outside [" + fmt("%g", lo) + ", " + fmt("%g", hi) + "]");
  return v;
}

Options parse(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) throw std::invalid_argument(a + " needs a value");
      return argv[++i];
    };
    if (a == "--run")
      o.run = value();
    else if (a == "--best")
      o.best = true;
    else if (a == "--checkpoint")
      o.checkpoint = value();
    else if (a == "--config")
      o.config = value();
    else if (a == "--out")
      o.out = value();
    else if (a == "--episodes")
      o.episodes = int(parse_integer(a, value(), 1, 10000));
    else if (a == "--seed")
      o.seed = uint64_t(parse_integer(a, value(), 0, INT64_MAX));
    else if (a == "--width")
      o.width = int(parse_integer(a, value(), 16, 4096));
    else if (a == "--height")
      o.height = int(parse_integer(a, value(), 16, 4096));
    else if (a == "--fps")
      o.fps = int(parse_integer(a, value(), 1, 240));
    else if (a == "--max-steps")
      o.max_steps = int(parse_integer(a, value(), 1, 100000000));
    else if (a == "--max-seconds")
      o.max_seconds = parse_number(a, value(), 1e-6, 1e7);
    else if (a == "--distance")
      o.camera.distance = parse_number(a, value(), 1e-6, 1e6);
    else if (a == "--azimuth")
      o.camera.azimuth = parse_number(a, value(), -360, 360);
    else if (a == "--elevation")
      o.camera.elevation = parse_number(a, value(), -90, 90);
    else if (a == "--no-overlay")
      o.overlay = false;
    else if (a == "--view-check")
      o.view_check = true;
    else if (a == "--ffmpeg")
      o.ffmpeg = value();
    else if (a == "-h" || a == "--help") {
      std::cout << kUsage;
      std::exit(0);
    } else
      throw std::invalid_argument("unknown option '" + a + "' (see --help)");
  }
  if (!o.run.empty() && !o.checkpoint.empty())
    throw std::invalid_argument("--run RUN and --checkpoint DIR both name a policy: give one (see --help)");
  if (o.run.empty() && o.checkpoint.empty() && o.config.empty())
    throw std::invalid_argument(
        "name the policy with --run RUN, --checkpoint DIR or --config EXPERIMENT.txtpb (see --help)");
  if (o.best && o.run.empty()) throw std::invalid_argument("--best goes with --run RUN (it reads RUN/best)");
  if (o.out.empty()) throw std::invalid_argument("--out FILE.mp4|FILE.gif|FOLDER/ is required (see --help)");
  return o;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    const Options o = parse(argc, argv);
    // What can fail quickly fails before the policy is loaded and anything is rendered.
    tools::video_kind(o.out);
    const std::string ffmpeg = tools::find_ffmpeg(o.ffmpeg);
    const std::string dir = !o.run.empty() ? tools::run_policy_dir(o.run, o.best) : o.checkpoint;
    const tools::RunPolicy rp = o.config.empty() ? tools::load_run_policy(dir) : tools::config_policy(o.config, dir);
    const robots::Task& task = *rp.task;
    const robots::TaskSpec& spec = task.spec();
    Policy policy(rp.policy);
    if (policy.obs_dim() != spec.obs_dim || policy.act_dim() != spec.act_dim)
      throw std::runtime_error(dir + ": the policy takes " + std::to_string(policy.obs_dim()) +
                               " observations and gives " + std::to_string(policy.act_dim()) + " actions; task '" +
                               spec.name + "' has " + std::to_string(spec.obs_dim) + " and " +
                               std::to_string(spec.act_dim));
    std::fprintf(
        stderr, "farm-play: %s: task %s, %s policy v%llu (%s), %d episode%s from seed %llu to %s (%dx%d, %d fps)\n",
        dir.empty() ? (o.config + " (untrained)").c_str() : dir.c_str(), spec.name.c_str(),
        rp.config.algorithm().c_str(), (unsigned long long)rp.policy.version, rp.policy.layout.describe().c_str(),
        o.episodes, o.episodes == 1 ? "" : "s", (unsigned long long)o.seed, o.out.c_str(), o.width, o.height, o.fps);

    tools::OffscreenRenderer renderer(o.width, o.height);
    tools::VideoWriter writer(o.out, o.width, o.height, o.fps, ffmpeg);
    tools::PlayView view(task, o.camera);
    std::vector<unsigned char> rgb(size_t(o.width) * o.height * 3);
    std::vector<float> obs(size_t(spec.obs_dim)), act(size_t(spec.act_dim)), metrics(spec.metric_names.size());
    std::mt19937_64 unused_rng;  // the deterministic policy draws no noise
    double min_coverage = 1, sum_coverage = 0;
    int64_t coverage_frames = 0, first_lost = -1, min_pixels = INT64_MAX;

    int64_t total_frames = 0;
    for (int e = 0; e < o.episodes; ++e) {
      auto state = task.make_state();
      uint64_t seed_state = mix_seed(o.seed, uint64_t(e));
      task.reset(*state, splitmix64(seed_state), obs.data());
      // The model this episode runs on (a terrain, randomized dynamics) is the one drawn.
      renderer.set_model(task.model_of(*state));
      view.start_episode(*state, renderer.model(), renderer.pose(state->data));
      renderer.set_camera_distance(view.distance());
      const double t0 = state->data->time;
      int64_t frame = 0;    // this episode's frames so far; frame k shows simulated time k / fps
      int64_t pending = 0;  // frames of the image in `rgb` not yet written
      int steps = 0;
      // Draws the pose into `rgb` with the overlay of the state now.
      auto draw = [&](double t) {
        const mjData* pose = renderer.pose(state->data);
        mjvCamera cam;
        view.aim(*state, pose, cam);
        // First column: where the episode is and its return; then the task's metrics so far, in
        // columns of at most as many rows.
        tools::OffscreenRenderer::Overlay left, right;
        std::vector<tools::OffscreenRenderer::Overlay> columns;
        if (o.overlay) {
          auto row = [](tools::OffscreenRenderer::Overlay& to, const std::string& name, const std::string& value) {
            to.names += (to.names.empty() ? "" : "\n") + name;
            to.values += (to.values.empty() ? "" : "\n") + value;
          };
          row(left, spec.name, "episode " + std::to_string(e + 1) + " of " + std::to_string(o.episodes));
          row(left, "step",
              std::to_string(state->step) + " of " + std::to_string(spec.max_episode_steps) + ", " + fmt("%.2f s", t));
          row(left, "return", fmt("%.2f", state->episode_return));
          if (!metrics.empty()) task.episode_metrics(*state, metrics.data());
          for (size_t k = 0; k < metrics.size(); ++k) row(right, spec.metric_names[k], fmt("%.3f", metrics[k]));
          for (const auto& [name, value] : view.rows(*state, pose)) row(right, name, value);
          columns.push_back(left);
          tools::OffscreenRenderer::Overlay column;
          std::istringstream names(right.names), values(right.values);
          for (std::string name, value; std::getline(names, name) && std::getline(values, value);) {
            if (std::count(column.names.begin(), column.names.end(), '\n') + 1 >= kOverlayRows) {
              columns.push_back(column);
              column = {};
            }
            row(column, name, value);
          }
          if (!column.names.empty()) columns.push_back(column);
        }
        renderer.render(
            cam, [&](mjvScene& scn) { view.decorate(*state, pose, scn); }, columns, rgb.data());
      };
      auto flush = [&]() {
        for (; pending > 0; --pending) writer.write(rgb.data());
      };
      // After a physics step: the frames whose time has come show this pose (one render, written
      // once the next render or the episode's end says what they show: the last frames of an
      // episode carry its final return and metrics).
      auto emit_frames = [&]() {
        const double t = state->data->time - t0;
        if (t + kFrameSlack / o.fps < double(frame) / o.fps) return;
        flush();
        draw(t);
        if (o.view_check) {
          const auto c = renderer.coverage([&](int body) { return view.is_robot_body(body); });
          min_coverage = std::min(min_coverage, c.share);
          min_pixels = std::min(min_pixels, c.pixels);
          sum_coverage += c.share;
          ++coverage_frames;
          if (c.pixels < kMinRobotPixels && first_lost < 0) first_lost = total_frames + frame;
        }
        while (t + kFrameSlack / o.fps >= double(frame) / o.fps) {
          ++pending;
          ++frame;
        }
      };
      emit_frames();
      state->after_physics_step = emit_frames;
      robots::StepResult r;
      for (;;) {
        policy.act(obs.data(), 1, unused_rng, true, act.data(), nullptr);
        r = task.step(*state, act.data(), obs.data());
        ++steps;
        if (r.terminated || r.truncated || (o.max_steps > 0 && steps >= o.max_steps)) break;
        if (o.max_seconds > 0 && state->data->time - t0 >= o.max_seconds * (1 - 1e-9)) break;
      }
      state->after_physics_step = nullptr;
      // The last image again, with the episode's final return and metrics.
      if (o.overlay && pending > 0) draw(state->data->time - t0);
      flush();
      total_frames += frame;
      if (!metrics.empty()) task.episode_metrics(*state, metrics.data());
      std::string line = "episode " + std::to_string(e + 1) + " of " + std::to_string(o.episodes) + ": return " +
                         fmt("%.2f", state->episode_return) + ", " + std::to_string(state->step) + " steps (" +
                         (r.terminated  ? "terminated"
                          : r.truncated ? "truncated"
                                        : "cut short") +
                         "), " + fmt("%.2f s", state->data->time - t0) + ", " + std::to_string(frame) + " frames";
      for (size_t k = 0; k < metrics.size(); ++k) line += ", " + spec.metric_names[k] + " " + fmt("%.4f", metrics[k]);
      std::printf("%s\n", line.c_str());
      std::fflush(stdout);
    }
    writer.finish();
    std::printf("wrote %s: %lld frames, %dx%d at %d fps (%.2f s)\n", o.out.c_str(), (long long)writer.frames(), o.width,
                o.height, o.fps, double(writer.frames()) / o.fps);
    if (o.view_check) {
      std::printf(
          "view: the robot (body '%s' and what hangs from it) covers %.2f %% (%lld pixels) to %.2f %% (mean) of the "
          "scene in %lld frames\n",
          view.root_name().c_str(), 100 * min_coverage, (long long)min_pixels,
          100 * sum_coverage / std::max<int64_t>(1, coverage_frames), (long long)coverage_frames);
      if (first_lost >= 0) {
        std::fprintf(stderr, "farm-play: the robot left the picture at frame %lld (covers fewer than %lld pixels)\n",
                     (long long)first_lost, (long long)kMinRobotPixels);
        return 3;
      }
    }
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "farm-play: %s\n", e.what());
    return 2;
  }
}
