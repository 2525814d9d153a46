// Evaluates a trained mCLARI policy on each of the six terrains (mCLARI thesis §5.3): deterministic
// episodes from a learner checkpoint, reporting mean efficiency, falls and targets reached per
// terrain against the best fixed (group, f) of a characterization sweep (farm-mclari-sweep's
// best.csv). Prints a Markdown table; --out also writes it to a file.
// With --events FILE it also keeps a record for programs (common/event_log.h): one JSON object a
// line with "event" and "elapsed_s" (seconds since farm-mclari-eval started). Kinds:
//   policy  as the printed "policy:" line: checkpoint, updates, layout; and episodes (a terrain),
//           seed, best (--best's file; "" without)
//   row     one per terrain, as its row of the table: terrain (0 ..), terrain_name, episodes,
//           efficiency, falls, reached, frequency_hz (the means and counts of its episodes),
//           distance (mean), fixed (the sweep's best fixed point on it: group_name, frequency_hz,
//           efficiency, seconds (0: best.csv does not say); null without --best or a row for the
//           terrain) and share_of_fixed (efficiency / fixed efficiency; null without fixed)
//   note    the table's note on a comparison that is not like for like: kind "unequal_lengths"
//           (ran_s: how long the fixed points ran, episodes_up_to_s) or "lengths_unknown"
//           (episodes_up_to_s); best (the file); text (the note as printed)
//   wrote   the table written to --out: path
//   trace   the --trace file written: path, episodes (one a terrain), steps (its rows)
// Human output (stdout and stderr) stays what it is; tests and tools read the record.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <memory>
#include <mutex>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "cli.h"
#include "config.h"
#include "config_policy.h"
#include "event_log.h"
#include "mclari/mclari_task.h"
#include "mclari/phase_groups.h"
#include "mclari/terrain.h"
#include "meter.h"
#include "mlp.h"
#include "rollout.h"
#include "task_specs.h"

namespace mclari = farm::robots::mclari;

namespace {

struct Best {
  std::string group_name;
  int frequency = 0;
  double efficiency = 0;
  double seconds = 0;  // how long the fixed point ran; 0: best.csv does not say (older sweeps)
};

// The fields of one CSV line: commas split it except inside double quotes (a group name such as
// "(pi/2, 0, pi)"); a line ending in CR (a file saved on Windows) loses it.
std::vector<std::string> csv_fields(std::string line) {
  if (!line.empty() && line.back() == '\r') line.pop_back();
  std::vector<std::string> fields(1);
  bool quoted = false;
  for (const char c : line) {
    if (c == '"')
      quoted = !quoted;
    else if (c == ',' && !quoted)
      fields.emplace_back();
    else
      fields.back() += c;
  }
  return fields;
}

// terrain -> best fixed point, from best.csv (farm-mclari-sweep's: terrain, group_name,
// frequency_hz and efficiency, found by the header's names, and seconds where the sweep wrote it).
// Every figure is checked whole: a table against a misread reference would look right and be wrong.
std::map<int, Best> read_best(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw std::runtime_error("cannot read " + path);
  std::string line;
  if (!std::getline(in, line)) throw std::runtime_error(path + ": empty, expected a header line");
  const auto header = csv_fields(line);
  auto column = [&](const std::string& name, bool required) {
    for (size_t i = 0; i < header.size(); ++i)
      if (header[i] == name) return int(i);
    if (required) throw std::runtime_error(path + ": the header has no column '" + name + "'");
    return -1;
  };
  const int c_terrain = column("terrain", true), c_group = column("group_name", true),
            c_frequency = column("frequency_hz", true), c_efficiency = column("efficiency", true),
            c_seconds = column("seconds", false);
  std::map<int, Best> best;
  int row = 1;
  while (std::getline(in, line)) {
    ++row;
    if (line.empty() || line == "\r") continue;
    const auto f = csv_fields(line);
    const std::string where = path + ":" + std::to_string(row) + ": ";
    if (f.size() != header.size())
      throw std::runtime_error(where + std::to_string(f.size()) + " fields where the header has " +
                               std::to_string(header.size()));
    auto number = [&](int c) {
      size_t used = 0;
      double v = 0;
      try {
        v = std::stod(f[c], &used);
      } catch (const std::exception&) {
        used = 0;
      }
      if (used == 0 || used != f[c].size() || !std::isfinite(v))
        throw std::runtime_error(where + header[c] + " '" + f[c] + "' is not a finite number");
      return v;
    };
    const double terrain = number(c_terrain);
    if (terrain != std::floor(terrain) || terrain < 0 || terrain >= mclari::kNumTerrains)
      throw std::runtime_error(where + "terrain " + f[c_terrain] + " is not one of 0.." +
                               std::to_string(mclari::kNumTerrains - 1));
    if (best.count(int(terrain)))
      throw std::runtime_error(where + "terrain " + f[c_terrain] + " appears a second time");
    Best b;
    b.group_name = f[c_group];
    b.frequency = int(number(c_frequency));
    b.efficiency = number(c_efficiency);
    if (b.efficiency <= 0) throw std::runtime_error(where + "efficiency " + f[c_efficiency] + " is not above 0");
    if (c_seconds >= 0) b.seconds = number(c_seconds);
    best[int(terrain)] = b;
  }
  return best;
}

// One deterministic episode per terrain, each step's gait and figures as CSV rows: what the
// policy does, where the table shows only its means. Returns the steps (rows) written.
int write_trace(const std::string& path, const farm::config::MclariConfig& mc_cfg, const farm::PolicyParams& params,
                uint64_t seed) {
  std::ofstream out(path);
  if (!out) throw std::runtime_error("cannot write " + path);
  out << "terrain,terrain_name,step,frequency_hz,group,group_name,power_w,speed_mm_s,efficiency,reward,end\n";
  farm::Policy policy(params);
  std::mt19937_64 unused_rng;  // deterministic: no noise is drawn
  auto mc = mc_cfg;
  mc.clear_hfield_png();
  const farm::robots::McLariTask task(mc);  // holds all six terrain models; reset_on picks one
  auto state = task.make_state();
  std::vector<float> obs(size_t(task.spec().obs_dim)), act(size_t(task.spec().act_dim));
  int rows = 0;
  for (int t = 0; t < mclari::kNumTerrains; ++t) {
    task.reset_on(*state, seed + 1000 * t, t, obs.data());
    for (int k = 1; k <= task.spec().max_episode_steps; ++k) {
      policy.act(obs.data(), 1, unused_rng, true, act.data(), nullptr);
      const auto r = task.step(*state, act.data(), obs.data());
      const auto& f = static_cast<const farm::robots::McLariState&>(*state).last;
      const char* end = r.terminated ? "terminated" : r.truncated ? "truncated" : "";
      char line[400];
      std::snprintf(line, sizeof line, "%d,%s,%d,%d,%d,\"%s\",%.6e,%.5f,%.6f,%.6f,%s\n", t, mclari::terrain_name(t), k,
                    f.frequency, f.group, mclari::group_name(f.group).c_str(), f.power, f.speed_mm_s, f.efficiency,
                    r.reward, end);
      out << line;
      ++rows;
      if (r.terminated || r.truncated) break;
    }
  }
  if (!out) throw std::runtime_error("write failed: " + path);
  return rows;
}

struct TerrainResult {
  double efficiency = 0, frequency = 0, distance = 0;
  int falls = 0, reached = 0, episodes = 0;
};

}  // namespace

int main(int argc, char** argv) {
  std::string config_path, checkpoint, best_path, out_path, trace_path, events_path;
  int episodes = 10, threads = int(std::max(1u, std::thread::hardware_concurrency()));
  uint64_t seed = 7;
  farm::cli::App app("farm-mclari-eval");
  app.description(
      "Evaluates a trained mCLARI policy on each of the six terrains: deterministic episodes from a "
      "learner checkpoint, mean efficiency, falls and targets reached per terrain against the best fixed "
      "(group, f) of a characterization sweep; prints a Markdown table.");
  app.add_option("--config", config_path, "The experiment (EXPERIMENT.txtpb)")->required();
  app.add_option("--checkpoint", checkpoint, "The learner's checkpoint directory (runs/<experiment>/checkpoint)")
      ->required();
  // Each episode of a terrain has its own environment for the whole evaluation: 1,000 a terrain is
  // far beyond what the table needs (10) and still fits in memory.
  app.add_option("--episodes", episodes, "Deterministic episodes per terrain")
      ->check(CLI::Range(1, 1000))
      ->capture_default_str();
  app.add_option("--best", best_path,
                 "The sweep's best fixed point per terrain (SWEEP/best.csv), for the comparison column");
  app.add_option("--out", out_path, "The table to write (TABLE.md)");
  app.add_option("--threads", threads, "Threads, one terrain each (at most one per terrain)")
      ->check(CLI::Range(1, INT32_MAX))
      ->capture_default_str();
  app.add_option("--seed", seed, "Reset seed of the first episode")
      ->check(farm::cli::whole_number())
      ->capture_default_str();
  app.add_option("--trace", trace_path,
                 "Also run one episode per terrain and write the gait and figures of each step (STEPS.csv)");
  app.add_option("--events", events_path,
                 "Also write a record for programs to this file (JSON lines, appended): the policy, each row of the "
                 "table, its note, the table and trace written");
  if (const int rc = farm::cli::parse(app, argc, argv); rc >= 0) return rc;
  farm::EventLog events;
  events.set_start(farm::now_seconds());
  try {
    if (!events_path.empty()) events.open(events_path);
    const auto cfg = farm::robots::load_config_file(config_path);
    if (cfg.task().name() != "mclari")
      throw std::invalid_argument(config_path + ": task.name is '" + cfg.task().name() + "', expected 'mclari'");
    std::map<int, Best> best;
    if (!best_path.empty()) best = read_best(best_path);

    // A learner's checkpoint names its updates in its manifest; a policy folder without one has
    // them as its policy file's version (farm-policy-file --config).
    const bool has_manifest = std::filesystem::exists(std::filesystem::path(checkpoint) / "manifest.txtpb");
    const farm::tools::RunPolicy rp =
        has_manifest ? farm::tools::load_run_policy(checkpoint) : farm::tools::config_policy(config_path, checkpoint);
    if (has_manifest && rp.config.task().name() != "mclari")
      throw std::invalid_argument(checkpoint + ": its manifest's task is '" + rp.config.task().name() +
                                  "', expected 'mclari'");
    farm::PolicyParams policy = rp.policy;
    policy.version = uint64_t(rp.updates);

    threads = std::min(threads, mclari::kNumTerrains);
    std::vector<TerrainResult> results(mclari::kNumTerrains);
    std::atomic<int> next{0};
    // The first error of any thread (a policy that does not fit the task, say): the others stop
    // taking terrains, every thread is joined, and it is reported as the program's error.
    std::exception_ptr failure;
    std::mutex failure_mutex;
    std::mutex progress_mutex;
    int terrains_done = 0;
    const auto t0 = std::chrono::steady_clock::now();
    std::fprintf(stderr, "farm-mclari-eval: %d deterministic episodes on each of %d terrains, %d threads\n", episodes,
                 mclari::kNumTerrains, threads);
    auto terrains = [&]() {
      for (int t = next++; t < mclari::kNumTerrains; t = next++) {
        auto mc = cfg.task().mclari();
        mc.clear_terrains();
        mc.add_terrains(t);
        mc.clear_hfield_png();
        auto task = std::make_shared<farm::robots::McLariTask>(mc);
        const auto recs = farm::evaluate_policy(task, policy, episodes, seed + 1000 * t);
        TerrainResult& r = results[t];
        for (const auto& e : recs) {
          r.efficiency += e.metrics[0];
          r.falls += e.metrics[1] > 0.5f;
          r.reached += e.metrics[2] > 0.5f;
          r.frequency += e.metrics[4];
          r.distance += e.metrics[5];
          ++r.episodes;
        }
        r.efficiency /= r.episodes;
        r.frequency /= r.episodes;
        r.distance /= r.episodes;
        // Long work (a 150 Hz episode is 540,000 physics steps): say when each terrain is done.
        const std::lock_guard<std::mutex> lock(progress_mutex);
        std::fprintf(stderr,
                     "farm-mclari-eval: %s done, %d episodes, efficiency %.4f, %d falls (%d of %d terrains, %.0f s)\n",
                     mclari::terrain_name(t), r.episodes, r.efficiency, r.falls, ++terrains_done, mclari::kNumTerrains,
                     std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
      }
    };
    auto worker = [&]() {
      try {
        terrains();
      } catch (...) {
        next = mclari::kNumTerrains;
        const std::lock_guard<std::mutex> lock(failure_mutex);
        if (!failure) failure = std::current_exception();
      }
    };
    std::vector<std::thread> pool;
    for (int k = 1; k < threads; ++k) pool.emplace_back(worker);
    worker();
    for (auto& th : pool) th.join();
    if (failure) std::rethrow_exception(failure);

    std::ostringstream table;
    table << "| terrain | episodes | SAC efficiency | falls | targets reached | mean f [Hz] | best fixed (group, f) | "
             "best fixed efficiency | SAC / best |\n"
          << "| --- | --- | --- | --- | --- | --- | --- | --- | --- |\n";
    char line[512];
    std::vector<nlohmann::json> rows;
    for (int t = 0; t < mclari::kNumTerrains; ++t) {
      const auto& r = results[t];
      std::string fixed = "-", fixed_eff = "-", ratio = "-";
      nlohmann::json row = {{"terrain", t},
                            {"terrain_name", mclari::terrain_name(t)},
                            {"episodes", r.episodes},
                            {"efficiency", r.efficiency},
                            {"falls", r.falls},
                            {"reached", r.reached},
                            {"frequency_hz", r.frequency},
                            {"distance", r.distance},
                            {"fixed", nullptr},
                            {"share_of_fixed", nullptr}};
      if (best.count(t)) {
        const Best& b = best[t];
        row["fixed"] = {{"group_name", b.group_name},
                        {"frequency_hz", b.frequency},
                        {"efficiency", b.efficiency},
                        {"seconds", b.seconds}};
        row["share_of_fixed"] = r.efficiency / b.efficiency;
        fixed = b.group_name + ", " + std::to_string(b.frequency) + " Hz";
        std::snprintf(line, sizeof line, "%.4f", b.efficiency);
        fixed_eff = line;
        std::snprintf(line, sizeof line, "%.0f %%", 100.0 * r.efficiency / b.efficiency);
        ratio = line;
      }
      std::snprintf(line, sizeof line, "| %s | %d | %.4f | %d / %d | %d / %d | %.1f | %s | %s | %s |\n",
                    mclari::terrain_name(t), r.episodes, r.efficiency, r.falls, r.episodes, r.reached, r.episodes,
                    r.frequency, fixed.c_str(), fixed_eff.c_str(), ratio.c_str());
      table << line;
      rows.push_back(std::move(row));
    }
    // Rough ground's fixed gaits slow down over a long run (the robot settles into the height
    // field), so the fixed points only compare with episodes of the same length.
    const double episode_s = cfg.task().mclari().max_episode_steps() * cfg.task().mclari().step_seconds();
    std::string note;
    nlohmann::json note_event;
    for (const auto& [t, b] : best) {
      char text[400];
      if (b.seconds == 0) {
        note_event = {{"kind", "lengths_unknown"}, {"episodes_up_to_s", episode_s}};
        std::snprintf(text, sizeof text,
                      "note: %s does not say how long its fixed points ran; these episodes run up to %g s\n",
                      best_path.c_str(), episode_s);
      } else if (std::abs(b.seconds - episode_s) > 1e-9) {
        note_event = {{"kind", "unequal_lengths"}, {"ran_s", b.seconds}, {"episodes_up_to_s", episode_s}};
        std::snprintf(text, sizeof text,
                      "note: not like for like: the fixed points of %s ran %g s, these episodes up to %g s "
                      "(farm-mclari-sweep --seconds %g)\n",
                      best_path.c_str(), b.seconds, episode_s, episode_s);
      } else {
        continue;
      }
      note = text;
      note_event["best"] = best_path;
      note_event["text"] = note.substr(0, note.size() - 1);  // without its newline
      break;
    }
    if (!note.empty()) {
      table << "\n" << note;
      std::fprintf(stderr, "farm-mclari-eval: %s", note.c_str());
    }
    std::cout << "policy: " << checkpoint << " (" << rp.updates << " updates, " << policy.layout.describe() << ")\n"
              << table.str();
    events.write("policy", {{"checkpoint", checkpoint},
                            {"updates", rp.updates},
                            {"layout", policy.layout.describe()},
                            {"episodes", episodes},
                            {"seed", seed},
                            {"best", best_path}});
    for (auto& row : rows) events.write("row", std::move(row));
    if (!note.empty()) events.write("note", note_event);
    if (!out_path.empty()) {
      std::ofstream out(out_path);
      if (!out) throw std::runtime_error("cannot write " + out_path);
      out << table.str();
      out.close();
      if (!out) throw std::runtime_error("write failed: " + out_path);
      events.write("wrote", {{"path", out_path}});
    }
    if (!trace_path.empty()) {
      const int steps = write_trace(trace_path, cfg.task().mclari(), policy, seed);
      std::cout << "trace: one episode per terrain, every step, in " << trace_path << "\n";
      events.write("trace", {{"path", trace_path}, {"episodes", mclari::kNumTerrains}, {"steps", steps}});
    }
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "farm-mclari-eval: %s\n", e.what());
    return 2;
  }
}
