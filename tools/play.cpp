// farm-play: renders a trained run's deterministic policy, as the workers run it, on its task to a
// video (MP4, an animated GIF or PNG frames) without a GPU or a display: MuJoCo's renderer on
// OSMesa, frames piped to ffmpeg at the video's rate (not once per physics or control step), a
// camera that follows the robot, the episode's return and the task's metrics drawn on the frame
// and printed per episode.
// With --events FILE it also keeps a record for programs (common/event_log.h): one JSON object a
// line with "event" and "elapsed_s" (seconds since farm-play started). Kinds:
//   start    task, policy (the policy's folder; "" for --config's untrained one), config (--config;
//            "" without), algorithm, policy_version, episodes, seed, out, width, height, fps
//   episode  one per episode as it ends, as its printed line: index (1 ..), of, return, steps, how
//            it ended (terminated, truncated, cut_short: by --max-steps or --max-seconds), seconds
//            (simulated), frames, metrics (the task's episode metrics by name)
//   wrote    the video written: path, frames, width, height, fps, seconds (of video)
//   view     with --view-check, as its printed line: root_body (the robot: that body and what hangs
//            from it), frames, min_share, min_pixels, mean_share (of the scene the robot covers),
//            lost_frame (the first frame where it covers fewer than min_robot_pixels; null: none),
//            cut_frame (the first frame whose overlay has a row wider than its column; null:
//            none), cut_rows (the most such rows of a frame); exit 3 when either is not null
// Human output (stdout and stderr) stays what it is; tests and tools read the record.
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

#include "cli.h"
#include "config_policy.h"
#include "event_log.h"
#include "meter.h"
#include "mlp.h"
#include "offscreen_renderer.h"
#include "play_view.h"
#include "vec_env.h"
#include "video_writer.h"

using namespace farm;

namespace {

// The pixels of a frame's scene below which --view-check says the robot is out of the picture.
constexpr int64_t kMinRobotPixels = 20;
// Frame times are compared with this slack (in frames), so a clock of summed physics steps that
// lands a rounding error short of a frame's time still shows that frame.
constexpr double kFrameSlack = 1e-3;

struct Options {
  std::string run, checkpoint, config, out, events, ffmpeg = "ffmpeg";
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

// Declares the options into o.
void add_options(CLI::App& app, Options& o) {
  app.description(
      "Plays the deterministic policy of RUN/checkpoint (--best: RUN/best, the learner's best\n"
      "evaluation; --checkpoint: any such folder) for N episodes of its task and writes them to one\n"
      "video: .mp4 (H.264), .gif (looping) or numbered PNG frames in a folder. Episode i starts from\n"
      "the reset seed the worker's evaluation of N episodes from seed S gives its env i.");
  app.add_option("--run", o.run, "The run folder whose checkpoint/ (or best/) holds the policy");
  app.add_flag("--best", o.best, "With --run: RUN/best, the learner's best evaluation");
  app.add_option("--checkpoint", o.checkpoint, "A checkpoint or best folder holding the policy");
  app.add_option("--config", o.config,
                 "The experiment from this file, not from the checkpoint's manifest: with --checkpoint, for a "
                 "policy folder without one (docs/data/mclari_terrain_policy); alone, an untrained policy of the "
                 "experiment's algorithm, to look at a task and the camera before training");
  app.add_option("--out", o.out, "FILE.mp4, FILE.gif or FOLDER/ (numbered PNG frames)");
  app.add_option("--episodes", o.episodes, "Episodes to play")->check(CLI::Range(1, 10000))->capture_default_str();
  app.add_option("--seed", o.seed, "Reset seed of the first episode")
      ->check(CLI::Range(int64_t(0), INT64_MAX))
      ->capture_default_str();
  app.add_option("--width", o.width, "Frame width in pixels")->check(CLI::Range(16, 4096))->capture_default_str();
  app.add_option("--height", o.height, "Frame height in pixels")->check(CLI::Range(16, 4096))->capture_default_str();
  app.add_option("--fps", o.fps, "Frames per second of simulated time (the video plays in real time)")
      ->check(CLI::Range(1, 240))
      ->capture_default_str();
  app.add_option("--max-steps", o.max_steps,
                 "End each episode after this many control steps (default: the task's limit)")
      ->check(CLI::Range(1, 100000000));
  app.add_option("--max-seconds", o.max_seconds, "End each episode once this much time is simulated")
      ->check(farm::cli::within(1e-6, 1e7));
  app.add_option("--distance", o.camera.distance,
                 "Distance of the camera that follows the robot (default: from the robot's size)")
      ->check(farm::cli::within(1e-6, 1e6));
  app.add_option("--azimuth", o.camera.azimuth, "Azimuth of the camera in degrees (90 looks along +y)")
      ->check(farm::cli::within(-360, 360));
  app.add_option("--elevation", o.camera.elevation, "Elevation of the camera in degrees (negative: from above)")
      ->check(farm::cli::within(-90, 90));
  app.add_flag_callback(
      "--no-overlay", [&o] { o.overlay = false; }, "No text on the frames (return, step, time, the task's metrics)");
  app.add_flag("--view-check", o.view_check,
               "Also measure the share of each frame the robot covers; exit 3 when it leaves the picture (covers "
               "fewer than 20 pixels) or a row of the overlay is wider than its column");
  app.add_option("--ffmpeg", o.ffmpeg, "The ffmpeg program (default: ffmpeg on PATH)");
  app.add_option("--events", o.events,
                 "Also write a record for programs to this file (JSON lines, appended): the start, each episode, "
                 "the video written and the view check");
}

// The combinations of options that name one policy and an output.
void check_combinations(const Options& o) {
  if (!o.run.empty() && !o.checkpoint.empty())
    throw std::invalid_argument("--run RUN and --checkpoint DIR both name a policy: give one (see --help)");
  if (o.run.empty() && o.checkpoint.empty() && o.config.empty())
    throw std::invalid_argument(
        "name the policy with --run RUN, --checkpoint DIR or --config EXPERIMENT.txtpb (see --help)");
  if (o.best && o.run.empty()) throw std::invalid_argument("--best goes with --run RUN (it reads RUN/best)");
  if (o.out.empty()) throw std::invalid_argument("--out FILE.mp4|FILE.gif|FOLDER/ is required (see --help)");
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  farm::cli::App app("farm-play");
  add_options(app, o);
  if (const int rc = farm::cli::parse(app, argc, argv); rc >= 0) return rc;
  EventLog events;
  events.set_start(now_seconds());
  try {
    check_combinations(o);
    if (!o.events.empty()) events.open(o.events);
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
    events.write("start", {{"task", spec.name},
                           {"policy", dir},
                           {"config", o.config},
                           {"algorithm", rp.config.algorithm()},
                           {"policy_version", rp.policy.version},
                           {"episodes", o.episodes},
                           {"seed", o.seed},
                           {"out", o.out},
                           {"width", o.width},
                           {"height", o.height},
                           {"fps", o.fps}});

    tools::OffscreenRenderer renderer(o.width, o.height);
    tools::VideoWriter writer(o.out, o.width, o.height, o.fps, ffmpeg);
    tools::PlayView view(task, o.camera);
    std::vector<unsigned char> rgb(size_t(o.width) * o.height * 3);
    std::vector<float> obs(size_t(spec.obs_dim)), act(size_t(spec.act_dim)), metrics(spec.metric_names.size());
    std::mt19937_64 unused_rng;  // the deterministic policy draws no noise
    double min_coverage = 1, sum_coverage = 0;
    int64_t coverage_frames = 0, first_lost = -1, min_pixels = INT64_MAX;
    int64_t first_cut = -1;  // the first frame whose overlay has a row wider than its column
    int most_cut = 0;

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
        // First column: where the episode is and its return; then the task's metrics so far and
        // its own rows, in as many columns as the frame has room for (OffscreenRenderer::layout).
        tools::OffscreenRenderer::Overlay left;
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
          std::vector<std::pair<std::string, std::string>> task_rows;
          for (size_t k = 0; k < metrics.size(); ++k)
            task_rows.emplace_back(spec.metric_names[k], fmt("%.3f", metrics[k]));
          for (auto& r : view.rows(*state, pose)) task_rows.push_back(std::move(r));
          columns = renderer.layout(left, task_rows);
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
          most_cut = std::max(most_cut, renderer.cut_rows());
          if (renderer.cut_rows() > 0 && first_cut < 0) first_cut = total_frames + frame;
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
      nlohmann::json named = nlohmann::json::object();
      for (size_t k = 0; k < metrics.size(); ++k) {
        line += ", " + spec.metric_names[k] + " " + fmt("%.4f", metrics[k]);
        named[spec.metric_names[k]] = metrics[k];
      }
      std::printf("%s\n", line.c_str());
      std::fflush(stdout);
      const bool cut_short = !r.terminated && !r.truncated;
      events.write("episode", {{"index", e + 1},
                               {"of", o.episodes},
                               {"return", state->episode_return},
                               {"steps", state->step},
                               {"terminated", r.terminated},
                               {"truncated", r.truncated},
                               {"cut_short", cut_short},
                               {"seconds", state->data->time - t0},
                               {"frames", frame},
                               {"metrics", named}});
    }
    writer.finish();
    std::printf("wrote %s: %lld frames, %dx%d at %d fps (%.2f s)\n", o.out.c_str(), (long long)writer.frames(), o.width,
                o.height, o.fps, double(writer.frames()) / o.fps);
    events.write("wrote", {{"path", o.out},
                           {"frames", writer.frames()},
                           {"width", o.width},
                           {"height", o.height},
                           {"fps", o.fps},
                           {"seconds", double(writer.frames()) / o.fps}});
    if (o.view_check) {
      std::printf(
          "view: the robot (body '%s' and what hangs from it) covers %.2f %% (%lld pixels) to %.2f %% (mean) of the "
          "scene in %lld frames\n",
          view.root_name().c_str(), 100 * min_coverage, (long long)min_pixels,
          100 * sum_coverage / std::max<int64_t>(1, coverage_frames), (long long)coverage_frames);
      auto frame_or_null = [](int64_t f) { return f < 0 ? nlohmann::json(nullptr) : nlohmann::json(f); };
      events.write("view", {{"root_body", view.root_name()},
                            {"frames", coverage_frames},
                            {"min_share", min_coverage},
                            {"min_pixels", min_pixels},
                            {"mean_share", sum_coverage / std::max<int64_t>(1, coverage_frames)},
                            {"min_robot_pixels", kMinRobotPixels},
                            {"lost_frame", frame_or_null(first_lost)},
                            {"cut_frame", frame_or_null(first_cut)},
                            {"cut_rows", most_cut}});
      if (first_lost >= 0) {
        std::fprintf(stderr, "farm-play: the robot left the picture at frame %lld (covers fewer than %lld pixels)\n",
                     (long long)first_lost, (long long)kMinRobotPixels);
        return 3;
      }
      if (first_cut >= 0) {
        std::fprintf(stderr,
                     "farm-play: from frame %lld the overlay has up to %d row(s) wider than their column: a wider "
                     "--width, or --no-overlay\n",
                     (long long)first_cut, most_cut);
        return 3;
      }
    }
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "farm-play: %s\n", e.what());
    return 2;
  }
}
