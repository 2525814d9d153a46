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
#include "task_specs.h"

using namespace farm;

namespace {

std::atomic<bool> g_interrupted{false};
void on_signal(int) { g_interrupted = true; }

struct Options {
  std::string config_path;
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
  app.add_option("--config", o.config_path, "The experiment's config (text protobuf)")->required();
  app.add_flag("--resume", o.resume,
               "Carry on from the checkpoint in the run dir. Without it, an existing run dir is moved aside "
               "(renamed with a time stamp), never overwritten");
  app.add_option("--run-dir", o.run_dir, "The run's folder (default <run_root>/<experiment_id>)");
  farm::dds::add_bus_options(app, o.bus);
}

}  // namespace

int main(int argc, char** argv) {
  Options opt;
  farm::cli::App app("farm-learner");
  add_options(app, opt);
  if (const int rc = farm::cli::parse(app, argc, argv); rc >= 0) return rc;
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
