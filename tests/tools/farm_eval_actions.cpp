// farm_eval_actions CHECKPOINT_DIR OUT [--episodes N] [--seed S]: the actions a worker computes in an
// evaluation for a checkpoint's policy, written out for python/tests to compare with
// farm.load_policy's. The policy is what the learner publishes for the checkpoint's networks
// (read_saved_policy over the experiment of its manifest), passed through the wire message a worker
// receives (dds::to_wire, dds::from_wire), and run by the workers' evaluation (farm::evaluate_policy)
// over N episodes side by side. OUT: a first line "# obs_dim D act_dim A", then one line per env and
// step, its D observation entries and A action entries with 9 significant digits (a float exactly).
#include <google/protobuf/text_format.h>

#include <cstdio>
#include <exception>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>
#include <stdexcept>
#include <string>

#include "cli.h"
#include "config.h"
#include "dds.h"
#include "farm_config.pb.h"
#include "registry.h"
#include "rollout.h"
#include "task.h"
#include "task_specs.h"

namespace fs = std::filesystem;

int main(int argc, char** argv) {
  farm::cli::App app("farm_eval_actions");
  app.description("Writes the observations and actions of a worker's evaluation of a checkpoint's policy.");
  std::string dir, out_path;
  int episodes = 4;
  uint64_t seed = 5;
  app.add_option("checkpoint_dir", dir, "a checkpoint or best folder")->required()->check(CLI::ExistingDirectory);
  app.add_option("out", out_path, "the file to write")->required();
  app.add_option("--episodes", episodes, "episodes side by side")->check(CLI::Range(1, 1024))->capture_default_str();
  app.add_option("--seed", seed, "the evaluation's seed")->capture_default_str();
  if (const int rc = farm::cli::parse(app, argc, argv); rc >= 0) return rc;
  try {
    const fs::path manifest_file = fs::path(dir) / "manifest.txtpb";
    std::ifstream in(manifest_file);
    std::stringstream text;
    text << in.rdbuf();
    farm::config::CheckpointManifest m;
    if (!in || !google::protobuf::TextFormat::ParseFromString(text.str(), &m) || m.config_text().empty())
      throw std::runtime_error(manifest_file.string() + " is not a checkpoint manifest with its config_text");
    farm::config::ExperimentConfig cfg =
        farm::robots::parse_config_text(m.config_text(), manifest_file.string() + " config_text");
    farm::clear_output_paths(&cfg);  // as a worker does: the task is built, nothing written
    int64_t updates = 0;
    const farm::PolicyParams published =
        farm::read_saved_policy(cfg, farm::robots::task_spec(cfg.task()), dir, m.policy_version(), &updates);
    farm::msg::PolicyWeights wire;
    farm::dds::to_wire(published, cfg.experiment_id(), wire);
    const farm::PolicyParams received = farm::dds::from_wire(wire);

    std::FILE* out = std::fopen(out_path.c_str(), "w");
    if (!out) throw std::runtime_error("cannot write " + out_path);
    const std::shared_ptr<const farm::robots::Task> task = farm::robots::make_task(cfg.task());
    const int obs_dim = task->spec().obs_dim, act_dim = task->spec().act_dim;
    std::fprintf(out, "# obs_dim %d act_dim %d\n", obs_dim, act_dim);
    farm::evaluate_policy(task, received, episodes, seed, nullptr, 0,
                          [&](const float* obs, const float* act, int rows) {
                            for (int r = 0; r < rows; ++r) {
                              for (int i = 0; i < obs_dim; ++i)
                                std::fprintf(out, "%.9g ", obs[size_t(r) * obs_dim + i]);
                              for (int i = 0; i < act_dim; ++i)
                                std::fprintf(out, i + 1 < act_dim ? "%.9g " : "%.9g\n", act[size_t(r) * act_dim + i]);
                            }
                          });
    if (std::fclose(out) != 0) throw std::runtime_error("cannot write " + out_path);
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "farm_eval_actions: %s\n", e.what());
    return 1;
  }
}
