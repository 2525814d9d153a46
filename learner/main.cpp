// farm-learner: reads the options and the experiment, then runs the farm service
// (farm_service.cpp) with the experiment's algorithm from the registry (algorithms/registry.cpp).
#include <signal.h>

#include <atomic>
#include <cstdio>
#include <iostream>
#include <string>

#include "compute.h"
#include "config.h"
#include "dds.h"
#include "farm_service.h"

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

void usage() {
  std::cout << "usage: farm-learner --config FILE [--resume] [--run-dir DIR] [--domain D]\n"
               "                    [--dds-profiles FILE] [--security DIR]\n"
               "Trains the experiment in FILE with the workers that join on DDS domain D.\n"
               "Logs to stdout and <run-dir>/learner.csv; checkpoints to <run-dir>/checkpoint;\n"
               "the networks of the best evaluation so far to <run-dir>/best.\n"
               "--resume carries on from the checkpoint in the run dir. Without it, an existing\n"
               "run dir is moved aside (renamed with a time stamp), never overwritten.\n";
}

Options parse(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    std::string a = argv[i];
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) throw std::invalid_argument(a + " needs a value");
      return argv[++i];
    };
    if (farm::dds::parse_bus_flag(argc, argv, i, o.bus)) continue;
    if (a == "--config")
      o.config_path = value();
    else if (a == "--resume")
      o.resume = true;
    else if (a == "--run-dir")
      o.run_dir = value();
    else if (a == "-h" || a == "--help") {
      usage();
      std::exit(0);
    } else
      throw std::invalid_argument("unknown option '" + a + "' (see --help)");
  }
  if (o.config_path.empty()) throw std::invalid_argument("--config FILE is required (see --help)");
  return o;
}

}  // namespace

int main(int argc, char** argv) {
  Options opt;
  config::ExperimentConfig cfg;
  try {
    opt = parse(argc, argv);
    cfg = load_config_file(opt.config_path);
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
