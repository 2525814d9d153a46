// farm-learner: reads the options and the experiment, then runs the farm service
// (farm_service.cpp) with the experiment's algorithm from the registry (algorithms/registry.cpp).
#include <signal.h>

#include <atomic>
#include <cstdio>
#include <string>

#include "cli.h"
#include "compute.h"
#include "config.h"
#include "dds.h"
#include "farm_service.h"
#include "registry.h"
#include "task_specs.h"

using namespace farm;

namespace {

std::atomic<bool> g_interrupted{false};
void on_signal(int) { g_interrupted = true; }

struct Options {
  std::string config_path;
  std::string check_path;
  farm::dds::BusOptions bus;
  bool resume = false;
  std::string run_dir;  // default <run_root>/<experiment_id>
};

// Declares the options; --config is required.
void add_options(CLI::App& app, Options& o) {
  app.description(
      "Trains the experiment in FILE with the workers that join on DDS domain D.\n"
      "Logs to stdout, <run-dir>/learner.csv and <run-dir>/events.jsonl; checkpoints to <run-dir>/checkpoint;\n"
      "the networks of the best evaluation so far to <run-dir>/best.");
  auto* experiment = app.add_option_group("experiment", "--config to train, or --check to check a config");
  experiment->add_option("--config", o.config_path, "The experiment's config (text protobuf)");
  experiment->add_option("--check", o.check_path,
                         "Load and check the config in FILE as --config would (its task's model files and "
                         "spec, its algorithm's name), print one line and exit: 0 when it would run, 2 with "
                         "the loader's error (the file and field at fault). Joins no DDS domain");
  experiment->require_option(1);
  app.add_flag("--resume", o.resume,
               "Carry on from the checkpoint in the run dir. Without it, an existing run dir is moved aside "
               "(renamed with a time stamp), never overwritten");
  app.add_option("--run-dir", o.run_dir, "The run's folder (default <run_root>/<experiment_id>)");
  farm::dds::add_bus_options(app, o.bus);
}

// --check: the loader's checks, the task's spec as the learner builds it (a task of terms reads its
// model files), and the algorithm's registration; no participant, no run folder. One line on stdout
// for scripts: "ok config=FILE experiment=ID task=NAME obs=N act=N actions=N algorithm=NAME".
int check_config(const std::string& path) {
  try {
    const config::ExperimentConfig cfg = robots::load_config_file(path);
    const robots::TaskSpec spec = robots::task_spec(cfg.task());
    find_algorithm(cfg.algorithm());
    std::printf("ok config=%s experiment=%s task=%s obs=%d act=%d actions=%d algorithm=%s\n", path.c_str(),
                cfg.experiment_id().c_str(), spec.name.c_str(), spec.obs_dim, spec.act_dim, spec.num_actions,
                cfg.algorithm().c_str());
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "farm-learner: %s\n", e.what());
    return cli::kUsageExit;
  }
}

}  // namespace

int main(int argc, char** argv) {
  Options opt;
  farm::cli::App app("farm-learner");
  add_options(app, opt);
  if (const int rc = farm::cli::parse(app, argc, argv); rc >= 0) return rc;
  if (!opt.check_path.empty()) return check_config(opt.check_path);
  config::ExperimentConfig cfg;
  try {
    cfg = robots::load_config_file(opt.config_path);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "farm-learner: %s\n", e.what());
    return 2;
  }
  signal(SIGINT, on_signal);
  signal(SIGTERM, on_signal);
  // Under DDS Security: read the permissions again and refuse the workers they no longer grant.
  signal(SIGHUP, [](int) { farm::dds::request_grants_reload(); });
  configure_compute(cfg.torch_threads());
  try {
    FarmService farm({opt.bus, opt.resume, opt.run_dir}, cfg, g_interrupted);
    return farm.run();
  } catch (const std::exception& e) {
    std::fprintf(stderr, "farm-learner: %s\n", e.what());
    return 1;
  }
}
